"""The course around rtlab: lab steps (``labs/<step>/``), templates generated from the reference
kernels, and the autograder.

    from rtlab.course import grade, load_config, write_template, write_release
    write_template("00_primary", "my00")               # my00/kernels/shared/...
    report = grade("00_primary", "submission/")        # each test in its own process, PoCL
    write_release("student-release")                  # what students get: no solutions
"""
from ..errors import LabError
from .config import LabConfig, TestSpec, lab_names, load_config
from .grader import GradeReport, TestResult, grade
from .regions import find_regions, splice_regions, strip_regions, stubbed_functions
from .release import write_release
from .template import template_files, write_template

__all__ = ["LabConfig", "TestSpec", "lab_names", "load_config", "GradeReport", "TestResult", "grade",
           "LabError", "find_regions", "splice_regions", "strip_regions", "stubbed_functions",
           "template_files", "write_template", "write_release"]
