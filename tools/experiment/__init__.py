"""The paper's experiments (section IV) through the whole pipeline: online PI² from the paper's
starting points, and the learned adaptive gait against fixed step lengths (docs/EXPERIMENTS.md)."""
