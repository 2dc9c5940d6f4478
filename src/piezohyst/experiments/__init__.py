"""End-to-end experiments: the paper's, on the virtual rig."""

from .paper import PaperExperiment, run_paper_experiment

__all__ = ["PaperExperiment", "run_paper_experiment"]
