"""``python -m towerpipe.bench``: the benchmarks (:func:`towerpipe.bench.main`)."""

import sys

from towerpipe.bench import main

sys.exit(main())
