"""The ``panorecon`` command. Each subcommand's options are its config's fields (``panorecon.configs``): the
parser is made from them, the parsed options become the config, and the command's function (``commands`` and
the modules named in COMMANDS) gets only the config. Each subcommand imports only what it needs."""

from __future__ import annotations

import argparse
import errno
import importlib
import logging
import sys
import threading

from . import cli_types as T
from . import configs as K
from .cli_types import Parser, add_settings, build_config
from .configs import ABLATE_WRITES, DEMO_WRITES, MAX_RUNS, RENDER_WRITES, TRAIN_VIEWS, TRAIN_WRITES  # noqa: F401
from .io import PanoreconInputError

log = logging.getLogger("panorecon")

# every subcommand: its words -> (help, config class, "module:function" under panorecon); a group (scenes,
# teachers, sources) has no config
COMMANDS: dict[tuple[str, ...], tuple[str, type | None, str | None]] = {
    ("scenes",): ("list the built-in scenes", None, None),
    ("scenes", "list"): (
        "name, synthetic or real, ground truth, description",
        K.ScenesListConfig,
        "commands:scenes_list",
    ),
    ("scenes", "check"): (
        "every posed dataset panorama under ROOT: does its true depth agree with the other panoramas of its "
        "space and with the dataset's annotated planes? (exit 1 when one is flagged)",
        K.ScenesCheckConfig,
        "commands:scenes_check",
    ),
    ("render",): (
        "write pano.png, distance.npy (float32 metres, inf = sky) and mask.png",
        K.RenderConfig,
        "commands:render",
    ),
    ("gt-cloud",): (
        "the ground-truth coloured point cloud from the true distance",
        K.GtCloudConfig,
        "commands:gt_cloud",
    ),
    ("inspect",): ("look at a point cloud with pyvista", K.InspectConfig, "commands:inspect_cloud"),
    ("teachers",): ("depth teachers", None, None),
    ("teachers", "list"): ("teacher specs", K.ListConfig, "commands:teachers_list"),
    ("teachers", "train"): (
        "train the learned depth teacher on synthetic scene variants and export it to ONNX (for onnx:)",
        K.TeachersTrainConfig,
        "commands:teachers_train",
    ),
    ("sources",): ("point sources", None, None),
    ("sources", "list"): ("registered point sources", K.ListConfig, "commands:sources_list"),
    ("points",): (
        "build an initial point cloud with a point source and report its error",
        K.PointsConfig,
        "commands:points",
    ),
    ("train",): (
        "fit Gaussians from a point source to the scene's pseudo-labels",
        K.TrainCommandConfig,
        "commands:train",
    ),
    ("ablate",): (
        "run an ablation suite (eval/suites/*.toml): results.csv, results.md, plots, report.html",
        K.AblateConfig,
        "commands:ablate",
    ),
    ("bench",): (
        "the benchmark CI job: tiny suite + micro-benchmarks against a baseline",
        K.BenchConfig,
        "commands:bench",
    ),
    ("generate",): (
        "text -> 360° panorama (sliding-window diffusion with a seam block)",
        K.GenerateCommandConfig,
        "text2pano.command:run_generate",
    ),
    ("export",): (
        "export pseudo-label views + a point source's cloud as a COLMAP model or a nerfstudio dataset",
        K.ExportConfig,
        "export:run_export",
    ),
    ("view",): ("look at Gaussians, clouds and cameras in the browser (viser)", K.ViewConfig, "viewer:cmd_view"),
    ("mesh",): ("a triangle mesh from a point cloud (screened Poisson, pymeshlab)", K.MeshConfig, "mesh:cmd_mesh"),
    ("demo",): ("the main job on the default scene (render, cloud, screenshot)", K.DemoConfig, "demo:run_demo"),
}


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="panorecon", description=__doc__)
    p.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    subs = {(): p.add_subparsers(dest="command", required=True)}
    for words, (text, config, fn) in COMMANDS.items():
        sub = subs[words[:-1]].add_parser(words[-1], help=text)
        if config is None:
            subs[words] = sub.add_subparsers(dest="what", required=True)
            continue
        add_settings(sub, config)
        sub.set_defaults(fn=fn, config=config)
    return p


# OS errors that mean the user's paths or disk, not a bug: reported as one line like bad input
USER_OS_ERRORS = {
    errno.EACCES,
    errno.EPERM,
    errno.EROFS,
    errno.EEXIST,
    errno.ENOTDIR,
    errno.EISDIR,
    errno.ENOENT,
    errno.ENOSPC,
    errno.EDQUOT,
    errno.ENAMETOOLONG,
}


def _option_names(parser: argparse.ArgumentParser) -> dict[str, str]:
    """dest -> the option as typed (``--out``; a positional by its upper-case name), over every subcommand."""
    names = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                names.update(_option_names(sub))
        elif action.dest not in names:
            names[action.dest] = action.option_strings[-1] if action.option_strings else action.dest.upper()
    return names


def _parse(argv):
    """-> (config, "module:function", verbose), or an exit status: --help (0) or a rejected option, a path
    collision or a config that does not check (2, one line)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help (0) or a rejected option (2, its one line already printed)
        return e.code if isinstance(e.code, int) else 2
    problem = T.path_collisions(vars(args), _option_names(parser))
    try:
        config = None if problem else build_config(args.config, vars(args))
    except ValueError as e:
        problem = str(e)
    if problem:
        print(f"panorecon: error: {problem}", file=sys.stderr)
        return 2
    return config, args.fn, args.verbose


def main(argv: list[str] | None = None) -> int:
    """Parse (options are validated here: a bad one exits 2 before any work), refuse an output path that is an
    input or another output (``cli_types.path_collisions``), run, and turn every user mistake into one line
    ``panorecon: error: ...`` with exit status 2, and Ctrl-C / SIGTERM into one line with exit 130 / 143
    (``interrupts``); only panorecon's own bugs leave a traceback."""
    import signal

    from . import interrupts

    old = {s: signal.getsignal(s) for s in interrupts.SIGNALS}
    interrupts.install()
    try:
        parsed = _parse(argv)
    except KeyboardInterrupt as e:
        e = e if isinstance(e, interrupts.Interrupted) else interrupts.Interrupted(signal.SIGINT)
        print(e.line(), file=sys.stderr)
        return e.exit_code
    finally:
        _restore(old)
    if isinstance(parsed, int):
        return parsed
    config, fn, verbose = parsed
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format="%(name)s: %(message)s")
    module, name = fn.split(":")
    interrupts.install()
    try:
        try:
            return getattr(importlib.import_module(f"panorecon.{module}"), name)(config)
        finally:  # inside the try below: a signal while the handlers are put back is one line too
            _restore(old)
            interrupts.end_at_exit()
    except KeyboardInterrupt as e:
        e = e if isinstance(e, interrupts.Interrupted) else interrupts.Interrupted(signal.SIGINT)
        print(e.line(), file=sys.stderr)
        return e.exit_code
    except PanoreconInputError as e:
        print(f"panorecon: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        if e.errno not in USER_OS_ERRORS:
            raise
        where = " -> ".join(str(f) for f in (e.filename, e.filename2) if f is not None)
        print(f"panorecon: error: {where + ': ' if where else ''}{e.strerror or e}", file=sys.stderr)
        return 2


def _restore(handlers: dict) -> None:
    """Put back the signal handlers main() found (in-process callers, e.g. tests, keep theirs)."""
    import signal

    if threading.current_thread() is threading.main_thread():
        for s, h in handlers.items():
            signal.signal(s, h)


if __name__ == "__main__":
    sys.exit(main())
