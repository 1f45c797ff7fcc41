"""Run the README's Python examples as a user would, each in a directory of its own with the
repository's data/ beside it: python readme_examples.py README.md"""

import os
import re
import sys
import tempfile
from pathlib import Path

readme = Path(sys.argv[1]).resolve()
blocks = re.findall(r"```python\n(.*?)```", readme.read_text(encoding="utf-8"), re.S)
if not blocks:
    sys.exit(f"{readme}: no Python examples")
for index, block in enumerate(blocks):
    with tempfile.TemporaryDirectory() as work:
        os.symlink(readme.parent / "data", Path(work) / "data")
        os.chdir(work)
        exec(compile(block, f"README.md block {index}", "exec"), {})
        print(f"README block {index}: ran")
