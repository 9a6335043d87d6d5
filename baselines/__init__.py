"""Peer methods as point-source plug-ins, installed with panorecon but outside its core: registered through the
``panorecon.sources`` entry points exactly as a third party's source would be (``pyproject.toml``), and
imported by nothing in ``panorecon/``. ``moge-merge`` (MoGe's own merge, the ``moge`` extra), ``erp-direct``
(the teacher on the whole ERP), and the classical multi-view baselines on several panoramas of one scene:
COLMAP SfM (known-pose triangulation and incremental mapping) and COLMAP MVS (CUDA builds of pycolmap only)."""

from panorecon.io import PanoreconInputError


class BaselineUnavailableError(PanoreconInputError):
    """A baseline this environment cannot run; the message starts with 'n/a: ' and says what is missing."""
