"""L2E Studio: lidar to event-camera extrinsic calibration by mutual information.

The engine (everything here except :mod:`l2e_studio.app`) is plain functions and small
dataclasses over numpy arrays; the browser workbench in ``app/`` is a thin shell over it.
"""

__version__ = "0.1.0"
