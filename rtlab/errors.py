"""User-facing errors. Each says what went wrong and where; the CLI prints them in one line, no traceback."""


class RtlabError(Exception):
    """Base class: an error the user can act on (bad input, missing device, failed build)."""


class SceneError(RtlabError):
    """A scene could not be found, loaded or validated (missing file, malformed mesh, NaN vertices...)."""


class BackendError(RtlabError):
    """A backend or device is unavailable or unknown."""


class KernelBuildError(RtlabError):
    """A kernel failed to compile. The message carries the file, the defines and the compiler log."""


class KernelRunError(RtlabError):
    """A launched kernel failed on the device (a GPU's illegal memory access...). The message names
    the kernel and the device's own error."""


class VariantError(RtlabError):
    """An unknown variant name (traversal, intersection test, memory placement...)."""


class LabError(RtlabError):
    """A lab step, its grading config, a template or a submission is malformed (rtlab.course)."""


class InspectError(RtlabError):
    """Scene inspection cannot run (no OpenGL for off-screen rendering, a pixel outside the image...)."""


class RtlabWarning(UserWarning):
    """Something the user should know that does not stop the work (a mesh with zero-area triangles, a
    missing material library, coordinates float32 cannot resolve); the CLI prints it as one line."""
