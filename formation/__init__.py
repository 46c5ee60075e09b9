"""The ``formation`` command-line front end."""
