"""The columns of a run's robots.csv (one row per robot per tick), shared by the in-process
simulator, the multi-process summary, the figures and the files (a leaf module: the summary
reads them without importing the simulator that imports the summary)."""

ROBOT_COLUMNS = (
    "t", "robot", "formation", "x", "y", "theta", "px", "py", "ux", "uy", "v", "omega",
    "status", "slack", "h_formation", "h_obstacle", "h_formations",
)
