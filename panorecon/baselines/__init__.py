"""Classical multi-view baselines on several panoramas of one scene: COLMAP SfM (known-pose triangulation
and incremental mapping), COLMAP MVS (CUDA builds of pycolmap only) and OpenCV semi-global matching."""
from ..io import PanoreconInputError


class BaselineUnavailableError(PanoreconInputError):
    """A baseline this environment cannot run; the message starts with 'n/a: ' and says what is missing."""
