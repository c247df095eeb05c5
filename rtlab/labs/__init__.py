"""The course around rtlab: lab steps (``labs/<step>/``), templates generated from the reference
kernels, and the autograder.

    from rtlab.labs import grade, load_config, write_template
    write_template("00_primary")                       # labs/00_primary/template/...
    report = grade("00_primary", "submission/")        # each test in its own process, PoCL
"""
from .config import LabConfig, TestSpec, lab_names, load_config
from .grader import GradeReport, TestResult, grade
from .regions import LabError, find_regions, splice_regions, strip_regions, stubbed_functions
from .template import stale_template_files, template_files, write_template

__all__ = ["LabConfig", "TestSpec", "lab_names", "load_config", "GradeReport", "TestResult", "grade",
           "LabError", "find_regions", "splice_regions", "strip_regions", "stubbed_functions",
           "stale_template_files", "template_files", "write_template"]
