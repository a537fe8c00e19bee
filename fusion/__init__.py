"""fusion: MVS-to-Gaussian conversion, the differentiable splat renderer, masked training, merging, export, meshing."""
