"""Geometry kernels: leaves, voxelization, rays. Pure numpy/numba; no USD."""
