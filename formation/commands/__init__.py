"""One module per ``formation`` subcommand: each turns parsed arguments into calls of the layers
below (scenario, simulator, experiments, deploy) and what the user sees; :mod:`formation.cli`
parses the arguments and maps errors to exit statuses."""
