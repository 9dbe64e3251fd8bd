"""LIP networks: point preprocessing, the pose and translation modules, losses and their configuration."""
