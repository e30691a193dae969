"""The predictive-coding network (pc) and the backends that run its kernels (numpy, Warp CPU/CUDA)."""
