"""The IK problem, its search and its engines: the strategy's stages, fatrop's compiled programs, the batched engine
and the damped least squares."""
