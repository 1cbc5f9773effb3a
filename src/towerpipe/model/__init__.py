"""The networks and what they eat: PointNet and EdgeConv, window features and constrained sampling, model bundles, cards and the model choice."""
