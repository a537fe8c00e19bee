"""The column-grid k-NN moved to :mod:`core.knn` (shared by ``fusion.convert`` and ``classify``).

``fusion.knn`` stays importable as an alias of that very module object (not a copy), so that
``from fusion.knn import knn_grid`` and attribute patches on ``fusion.knn`` (the tests) act on ``core.knn``.
"""

import sys

from core import knn as _knn

sys.modules[__name__] = _knn
