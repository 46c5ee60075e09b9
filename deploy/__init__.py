"""Deploy: put agents and their configuration on robots over SSH, and control them."""
