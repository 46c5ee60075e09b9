"""The robot agent: the control step (pure functions) and, around it, the agent process."""
