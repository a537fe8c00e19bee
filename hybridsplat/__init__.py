"""hybridsplat: the application layer — CLI, pipeline stages, manifest and configuration."""

import os

# OpenMP spin-waiting (torch's default) slows multi-threaded kernels several-fold on small shared machines; the
# policy must be set before torch loads its OpenMP runtime. A value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
