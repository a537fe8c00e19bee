"""hybridsplat: the application layer — CLI, pipeline stages, manifest and configuration."""

import os
import warnings

# OpenMP spin-waiting (torch's default) slows multi-threaded kernels several-fold on small shared machines; the
# policy must be set before torch loads its OpenMP runtime. A value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# numba probes its TBB threading layer and, finding an older TBB, falls back to OpenMP with a warning that says
# nothing a user can act on.
warnings.filterwarnings("ignore", message="The TBB threading layer requires TBB version")

__version__ = "0.3.1"
