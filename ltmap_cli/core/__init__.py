"""The map itself: voxel storage, ray casting, the layers and their rules, projection.

Knows nothing of ROS, files, click or plotting. Import the pieces from their modules
(``ltmap_cli.core.layers``, ``ltmap_cli.core.projection``, ...); importing this package is cheap.
"""
