"""The paper's experiments: the scenarios (:mod:`.scenarios`), the runner over seeds and
configurations (:mod:`.runner`) and their figures (:mod:`.figures`)."""

from .runner import NAMES, RunSpec, run_experiments, run_one, specs

__all__ = ["NAMES", "RunSpec", "run_one", "run_experiments", "specs"]
