"""Collision checking: the robot's and the scene's convex primitives, signed distances batched over
samples and pairs with their gradients, and the clearance certified on the continuous trajectory
(docs/collision.md). Maths only: files are read by ``hoc_cli.io.collision_geometry``,
``hoc_cli.io.meshes`` and ``hoc_cli.io.task.collision``.
"""
