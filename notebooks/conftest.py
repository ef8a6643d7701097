"""Under ``pytest --nbmake``, notebooks run their quick variants (the committed outputs are full runs)."""

import os

os.environ.setdefault("SQUKF_NB_QUICK", "1")
