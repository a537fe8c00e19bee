"""Test-wide settings.

OpenMP spin-waiting (torch's default) makes multi-threaded kernels several times slower on small shared
machines; passive waiting must be chosen before torch is first imported, hence here.
"""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
