"""The output checks of the command line: :mod:`voxflex.outputs` (one implementation, which the Python API
uses as well)."""

from ..outputs import (
    RENDER_FILES,
    RESULT_EXTENSIONS,
    check_image_output,
    check_render_output,
    check_result_output,
    check_vtk_output,
    is_result_file,
    run_inputs,
)

__all__ = ["RENDER_FILES", "RESULT_EXTENSIONS", "check_image_output", "check_render_output", "check_result_output",
           "check_vtk_output", "is_result_file", "run_inputs"]
