"""The plugin contracts: the hooks, the registry that finds plugins through entry points, the
framework-plugin API (`FrameworkSpec`, `Framework`, `TrainContext`) and what `load_policy`
returns (`Policy`)."""
