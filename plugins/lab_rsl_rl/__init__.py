"""RSL-RL (rsl-rl-lib 5.x) as a lab framework plugin."""

import os

# RSL-RL imports GitPython, whose import fails where no git executable is found (containers
# often have none). lab never asks RSL-RL for git state (its logger stores no code diffs), so
# without git nothing is lost: GitPython is told to import quietly.
os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
