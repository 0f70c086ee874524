"""An example lab task plugin: a point mass reaching a random target on a plane."""
