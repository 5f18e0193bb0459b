"""Geometric multigrid on voxel grids: the hierarchy, the voxel stencil and their compiled kernels."""
