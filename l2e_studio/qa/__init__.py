"""Calibration QA for a dataset release (issue 9): held-out scores, repeatability and scene-count
studies, MI landscapes, uncertainty, guardrails and the HTML report.

Everything here builds on the engine's public API (:func:`l2e_studio.calibrate.calibrate`,
:class:`l2e_studio.objective.SceneStack`), headless and GUI-free; the CLI sub-commands
(``heldout``, ``study``, ``landscape``, ``export``, ``report``) and the app call the same functions.
"""

#: The six parameters of a local correction ``(dt, dw)`` of an extrinsic, camera frame:
#: translation in metres along x, y, z and rotation about the camera's x, y, z axes.
AXES = ("x", "y", "z", "rx", "ry", "rz")
UNITS = ("mm", "mm", "mm", "deg", "deg", "deg")
