"""Command-line tools of lip_ros (bag generation helpers, URDF generation, ...)."""
