"""Names and descriptions of the synthetic scenes, importable without Open3D (the scenes themselves are
built by ``synthetic.py``, which needs it): the registry lists them and builds one only when it is loaded."""

from __future__ import annotations

DEFAULT_WIDTH = 1024  # ERP width (pixels) of a synthetic scene when none is asked for
SCENE_SEED = 7

SYNTHETIC_SCENES = {
    "bedroom": "bedroom: bed with pillows and headboard, nightstands and lamp, wardrobe, desk, rug, window (indoor)",
    "bathroom": "luxury bathroom: tiled walls, marble tub, vanity with basin and mirror, toilet, plant (indoor)",
    "library": "library: wall shelves full of books, free-standing stacks, reading tables and chairs (indoor)",
    "exhibition-hall": (
        "indoor exhibition hall: art installations on pedestals, glass display cases, large posters, spotlights"
    ),
    "mountain": "mountain landscape: ridged terrain with rock and snow, sky at infinity (outdoor)",
    "grassland": "grassland with blue sky: rolling hills, yurts, a fence line, clouds (outdoor)",
    "beach": "waves on the beach: sand dunes, a wavy sea to the horizon, umbrellas and rocks (outdoor)",
    "city-plaza": (
        "outdoor city plaza: central fountain, stone benches, tiled ground, street lamps, buildings, open space"
    ),
}

VARIANT_SEP = "@"
VARIANT_PATTERN = f"NAME{VARIANT_SEP}K"


def split_variant(name: str) -> tuple[str, int | None]:
    """``"bedroom@3"`` -> ("bedroom", 3); a plain synthetic name -> (name, None). Raises ValueError with the
    reason for anything else (callers turn it into their own input error)."""
    if VARIANT_SEP not in name:
        if name not in SYNTHETIC_SCENES:
            raise ValueError(f"expected a synthetic scene ({', '.join(SYNTHETIC_SCENES)})")
        return name, None
    base, _, k = name.rpartition(VARIANT_SEP)
    if base not in SYNTHETIC_SCENES:
        raise ValueError(
            f"a variant {VARIANT_PATTERN} needs NAME one of the synthetic scenes ({', '.join(SYNTHETIC_SCENES)}), "
            f"not {base!r}"
        )
    if not (k.isascii() and k.isdigit()) or int(k) < 1 or str(int(k)) != k:
        hint = " (a range A..B is for a suite's scene list)" if ".." in k else ""
        raise ValueError(f"a variant {VARIANT_PATTERN} needs K an integer >= 1 without leading zeros, not {k!r}{hint}")
    return base, int(k)
