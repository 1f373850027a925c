"""The simulated lab: lab geometry, ball physics and launcher, the simulated WAM, seeded
trajectories, study rigs and the renderer (docs/architecture.md, the layer table)."""
