"""Warp kernels for the predictive-coding hot loops and their numpy reference."""
