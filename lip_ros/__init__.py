"""lip_ros: human motion capture in large spaces from LiDAR and body-worn IMUs."""

__version__ = "0.1.0"
