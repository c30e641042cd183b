"""Options that several commands share, each defined once: the same name, default, type and help text in
every command that takes it. ``tests/commands/test_options_alike.py`` reads every command's parser and holds
them so; where a command must differ (a default of its own, fewer choices), that test lists the difference
and says why.

Also the settings that options make together, each built and checked once from the command line, with an
error that names the option, the value and what was expected, and then passed down as one typed value:

* :func:`random_cables`: the cable randomisation (``--randomize-cable``, ``--cable-ranges``), a
  :class:`~dyndlo_vision.tasks.wrappers.RandomCables` or None;
* :func:`segmenter_config`: the segmenter of a video or photo (``--segmenter`` and its settings), a
  :class:`~dyndlo_vision.tracking.segmenters.SegmenterConfig`;
* :class:`ObservationChoice`: where the simulated loop's P_DLO comes from (``--observation`` with the noise
  model or the perception settings that go with it).

Heavy modules are imported inside the functions, so that ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from dyndlo_vision.control.sim_perception import LoopPerception
    from dyndlo_vision.tasks.wrappers import RandomCables
    from dyndlo_vision.tracking.segmenters import SegmenterConfig

#: A parser or an argument group of one.
_Parser = argparse._ActionsContainer
#: The first episode's seed of the commands that run a policy's episodes (``demo``, ``evaluate``).
FIRST_EPISODE_SEED = 100_000
#: The MuJoCo camera placed for the loop in every task's scene (``--camera``'s default).
LOOP_CAMERA = "tracking"
#: What each segmenter kind is, for ``--segmenter``'s help.
SEGMENTER_KINDS = {
    "learned": "learned, a CNN (--segmenter-model), for textured or cluttered scenes",
    "background": "background, contrast with a model of the scene without the cable",
    "hsv": "hsv, colour bounds (--hsv-lower, --hsv-upper)",
}
#: ``--hsv-lower`` and ``--hsv-upper`` when not given: every saturated, not too dark colour.
HSV_LOWER, HSV_UPPER = "0,80,60", "179,255,255"


# ------------------------------------------------------------------------------------------ the run


def add_task(
    p: _Parser,
    choices: Sequence[str] | None = None,
    default: str | None = "tip-control",
    help: str = "the task",
) -> None:
    """``--task``: one of ``choices`` (default: every task)."""
    from dyndlo_vision.tasks.registry import TASKS

    p.add_argument("--task", choices=list(choices or sorted(TASKS)), default=default, help=help)


def add_episodes(p: _Parser, default: int) -> None:
    """``--episodes``: how many episodes of a policy to run, from ``--seed`` on."""
    p.add_argument("--episodes", type=int, default=default,
                   help="episodes to run, on the seeds --seed, --seed + 1, ...")


def add_first_seed(p: _Parser) -> None:
    """``--seed`` of the commands that run a policy's episodes: the first episode's."""
    p.add_argument("--seed", type=int, default=FIRST_EPISODE_SEED,
                   help="seed of the first episode, which draws its start, target and any random cable")


def add_quiet(p: _Parser) -> None:
    """``--quiet``."""
    p.add_argument("--quiet", action="store_true", help="no progress bars on stderr")


def add_resume(p: _Parser) -> None:
    """``--resume`` of the commands that write a run folder."""
    p.add_argument("--resume", action="store_true", help="continue the run in --out from where it stopped")


def add_env_option(p: _Parser) -> None:
    """``--env-option KEY=VALUE`` (repeatable)."""
    p.add_argument(
        "--env-option",
        action="append",
        metavar="KEY=VALUE",
        help="task option of the task's environment, e.g. target=down or cable=chain (repeatable); it adds "
        "to, or replaces, the options a given policy was trained with (from the JSON beside it)",
    )


def add_multi_step(p: _Parser) -> None:
    """``--multi-step`` / ``--no-multi-step`` (None: the policy's own mode)."""
    p.add_argument(
        "--multi-step",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="re-plan every 0.04 s (multi-step episodes), or plan once (--no-multi-step); default: the "
        "policy's own mode, single-step for a policy that has none (a new, scripted or random one)",
    )


def add_robot(p: _Parser) -> None:
    """``--robot ARM``."""
    from dyndlo_vision.robots.feasibility import ROBOT_ARMS

    p.add_argument(
        "--robot",
        choices=sorted(ROBOT_ARMS),
        default=None,
        help="judge every plan on this arm's joint limits, as its driver does (IK with the tool down; joint "
        "positions, speeds, accelerations): a plan it cannot follow ends the episode with the avoid "
        "condition 'joints' (tasks with one TCP); default: the policy's own arm, none for a new policy",
    )


# ------------------------------------------------------------------------ what the policy observes


def add_obs_noise(p: _Parser, default: str = "none, the true P_DLO") -> None:
    """``--obs-noise MODEL.json|NAME``; ``default`` says what the command does without it."""
    p.add_argument(
        "--obs-noise",
        default=None,
        metavar="MODEL.json|NAME",
        help="observation-noise model the policy sees P_DLO (and the gripper's state) through: a JSON file "
        "written by ObservationNoiseModel.save, or a shipped one by name, 'packaged' (tip control's "
        f"one-camera tracker) or 'vaulting-two-cameras' (the vault loop's two-camera tracker); default: "
        f"{default}",
    )


def add_cable_options(p: _Parser) -> None:
    """``--randomize-cable`` and ``--cable-ranges``, read together by :func:`random_cables`."""
    from dyndlo_vision.tasks.wrappers import (
        BEYOND_TRAINING_CABLE_RANGES,
        CABLE_RANGES,
        DEFAULT_CABLE_RANGES,
        TASK_CABLE_RANGES,
        describe_cable_ranges,
    )

    vault = TASK_CABLE_RANGES[("vaulting", "beyond")]["length_m"]
    p.add_argument(
        "--randomize-cable",
        action="store_true",
        help="random cables: length, mass, Young's modulus and damping drawn from the episode's seed in the "
        f"training ranges ({describe_cable_ranges(DEFAULT_CABLE_RANGES)}), as --cable-ranges training",
    )
    p.add_argument(
        "--cable-ranges",
        choices=list(CABLE_RANGES),
        default=None,
        help="random cables drawn from these ranges, with or without --randomize-cable: training, or beyond "
        f"them ({describe_cable_ranges(BEYOND_TRAINING_CABLE_RANGES)}; vaulting's lengths "
        f"{vault[0]:g}-{vault[1]:g}x, as shorter cables do not fit around its box); default: the nominal "
        "cable, or the training ranges with --randomize-cable",
    )


def random_cables(args: argparse.Namespace, every_episodes: int = 1) -> RandomCables | None:
    """The cable randomisation ``--randomize-cable`` and ``--cable-ranges`` ask for (None: the nominal
    cable), a new cable every ``every_episodes`` episodes."""
    from dyndlo_vision.tasks.wrappers import RandomCables

    if args.cable_ranges is None and not args.randomize_cable:
        return None
    return RandomCables(args.cable_ranges or "training", every_episodes=every_episodes)


# ------------------------------------------------------------------------------ the camera and images


def add_camera(p: _Parser) -> None:
    """``--camera``: a MuJoCo camera of the task's scene (None: :data:`LOOP_CAMERA`)."""
    p.add_argument(
        "--camera",
        default=None,
        metavar="NAME",
        help=f"MuJoCo camera of the task's scene (default: {LOOP_CAMERA}, the camera placed for the loop)",
    )


def add_image_size(
    p: _Parser, width: int | None, height: int | None, unless: tuple[int, int, str] | None = None
) -> None:
    """``--width`` and ``--height`` in pixels, default ``width`` and ``height``; ``unless`` (width, height,
    why) says what None defaults stand for."""
    for k, (name, default) in enumerate((("width", width), ("height", height))):
        note = "" if unless is None else f" (default {unless[k]}, {unless[2]})"
        p.add_argument(f"--{name}", type=int, default=default, metavar="PX",
                       help=f"image {name} in pixels{note}")


def add_segmenter(p: _Parser, kinds: Sequence[str], default: str | None,
                  default_text: str = "") -> None:
    """``--segmenter``: one of ``kinds`` (:data:`SEGMENTER_KINDS`); ``default_text`` says what a None default
    means."""
    text = "; ".join(SEGMENTER_KINDS[k] for k in kinds)
    p.add_argument("--segmenter", choices=list(kinds), default=default,
                   help=f"how the cable is found in an image: {text}" + (f"; default: {default_text}"
                                                                         if default_text else ""))


def add_segmenter_model(p: _Parser, default: str) -> None:
    """``--segmenter-model``: the learned segmenter's network (None: the command's ``default``)."""
    from dyndlo_vision.tracking.networks import SHIPPED_SUMMARIES

    p.add_argument(
        "--segmenter-model",
        default=None,
        metavar="FILE.onnx|NAME",
        help="with --segmenter learned: the network, an ONNX file from seg-train or a shipped one by name: "
        + ", ".join(f"{name} ({summary})" for name, summary in SHIPPED_SUMMARIES.items())
        + f"; default: {default}",
    )


def add_short_side(p: _Parser) -> None:
    """``--short-side``: the learned segmenter's input size."""
    p.add_argument(
        "--short-side",
        type=int,
        default=None,
        metavar="PX",
        help="with --segmenter learned: each image's shorter side is resized to this before the network "
        "(default: the network's own, 240 for cable-segmenter, 480 for the others); for a cable 1-3 px wide, "
        "enlarge: 720 for 640x480 images",
    )


def add_hsv_bounds(p: _Parser) -> None:
    """``--hsv-lower`` and ``--hsv-upper``: the bounds of ``--segmenter hsv``."""
    p.add_argument(
        "--hsv-lower",
        metavar="H,S,V",
        help="with --segmenter hsv: the lower bound, OpenCV's HSV (H 0-179, S and V 0-255; default "
        f"{HSV_LOWER})",
    )
    p.add_argument(
        "--hsv-upper",
        metavar="H,S,V",
        help=f"with --segmenter hsv: the upper bound (default {HSV_UPPER}); a lower H above the upper H "
        "wraps through red",
    )


def parse_hsv(text: str, option: str) -> tuple[int, int, int]:
    """An OpenCV HSV triple ``H,S,V`` with H in 0..179 and S, V in 0..255.

    Raises:
        ValueError: On anything else, naming the option and the text.
    """
    parts = [s.strip() for s in str(text).split(",")]
    try:
        values = [float(s) for s in parts]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) and v == round(v) for v in values):
        raise ValueError(f"{option} must be three integers H,S,V, got {text!r}")
    h, s, v = (int(c) for c in values)
    if not (0 <= h <= 179 and 0 <= s <= 255 and 0 <= v <= 255):
        raise ValueError(f"{option} must have H in 0..179 and S, V in 0..255 (OpenCV's HSV), got {text!r}")
    return h, s, v


def segmenter_config(args: argparse.Namespace, default_model: str | None = None,
                     **background: Any) -> SegmenterConfig:
    """The segmenter ``--segmenter`` and its settings name (``track``, ``segment``), checked: a setting of
    another kind is an error. ``default_model``: the learned network when ``--segmenter-model`` is not given
    (None: the shipped default); ``background``: the background segmenter's settings
    (:class:`~dyndlo_vision.tracking.segmenters.SegmenterConfig`'s ``background``, ``open_radius``).

    Raises:
        ValueError: Naming the option, its value and what was expected.
    """
    from dyndlo_vision.tracking.segmenters import SegmenterConfig

    kind = args.segmenter
    own = {"learned": ("--segmenter-model", "--short-side"), "hsv": ("--hsv-lower", "--hsv-upper")}
    for owner, options in own.items():
        for option in options:
            value = getattr(args, option[2:].replace("-", "_"))
            if value is not None and kind != owner:
                raise ValueError(f"{option} is for --segmenter {owner}, not {kind}")
    if kind == "learned":
        if args.segmenter_model is not None:
            from dyndlo_vision.tracking.networks import check_network

            check_network(args.segmenter_model, "--segmenter-model")
        if args.short_side is not None and args.short_side < 16:
            raise ValueError(f"--short-side must be at least 16 pixels, got {args.short_side}")
        model = args.segmenter_model or default_model
        return SegmenterConfig("learned", model=None if model is None else str(model),
                               short_side=args.short_side)
    if kind == "hsv":
        lower = parse_hsv(args.hsv_lower or HSV_LOWER, "--hsv-lower")
        upper = parse_hsv(args.hsv_upper or HSV_UPPER, "--hsv-upper")
        if lower[1] > upper[1] or lower[2] > upper[2]:
            raise ValueError(f"--hsv-lower S,V must not exceed --hsv-upper S,V: {','.join(map(str, lower))} "
                             f"vs {','.join(map(str, upper))}")
        return SegmenterConfig("hsv", hsv_lower=lower, hsv_upper=upper)
    return SegmenterConfig("background", **background)


# ------------------------------------------------------------------------ the simulated loop's P_DLO


@dataclass(frozen=True)
class ObservationChoice:
    """Where the simulated loop's P_DLO comes from (``demo``'s ``--observation``), with the settings of that
    source, checked together when built by :meth:`from_args`.

    Attributes:
        kind: ``tracked`` (camera, tracker, filter), ``true``, ``noisy`` or ``frozen``
            (:data:`~dyndlo_vision.control.episode.OBSERVATIONS`).
        noise: ``noisy``: the noise model's name or file, as given or the task's own (None otherwise).
        noise_model: ``noisy``: that model, loaded (the task's own loop tracker's when none was named).
        segmenter: ``tracked``: ``learned`` or ``background`` (None: the scene's own,
            :func:`~dyndlo_vision.control.sim_perception.default_segmenter`).
        segmenter_model, segmenter_scale: ``tracked``, learned segmenter: its network and enlargement (None:
            the loop's, :func:`~dyndlo_vision.control.sim_perception.loop_segmenter`).
        views: ``tracked``: the cameras tracked, 1 or 2 (None: as many as the scene has).
        latency_ms: ``tracked``: the camera's delay.
    """

    kind: str = "tracked"
    noise: str | None = None
    noise_model: Any = None
    segmenter: str | None = None
    segmenter_model: str | None = None
    segmenter_scale: float | None = None
    views: int | None = None
    latency_ms: float = 0.0

    @classmethod
    def from_args(cls, args: argparse.Namespace, task: str) -> ObservationChoice:
        """The observation the options ask for in ``task``, checked (the noise model is loaded here).

        Raises:
            ValueError: An option of another observation, or a value out of its range (naming both).
            FileNotFoundError: A noise model or network file that does not exist.
        """
        from dyndlo_vision.control.sim_perception import MAX_LATENCY_S

        kind = args.observation
        tracked_only = {"--segmenter": args.segmenter, "--segmenter-model": args.segmenter_model,
                        "--segmenter-scale": args.segmenter_scale, "--views": args.views,
                        "--latency-ms": args.latency_ms or None}
        for option, value in (*tracked_only.items(), ("--obs-noise", args.obs_noise)):
            wanted = "noisy" if option == "--obs-noise" else "tracked"
            if value is not None and kind != wanted:
                raise ValueError(f"{option} applies to the {wanted} observation, not to {kind!r}")
        if not 0.0 <= args.latency_ms <= 1000.0 * MAX_LATENCY_S:  # also NaN
            raise ValueError(f"--latency-ms must be in [0, {1000.0 * MAX_LATENCY_S:g}] ms, got "
                             f"{args.latency_ms}")
        if args.segmenter == "background":
            for option in ("--segmenter-model", "--segmenter-scale"):
                if tracked_only[option] is not None:
                    raise ValueError(f"{option} is for --segmenter learned, not background")
        if args.segmenter_model is not None:
            from dyndlo_vision.tracking.networks import check_network

            check_network(args.segmenter_model, "--segmenter-model")
        if args.segmenter_scale is not None:
            from dyndlo_vision.tracking.segmenters import MAX_SCALE, MIN_SCALE

            if not MIN_SCALE <= args.segmenter_scale <= MAX_SCALE:  # also NaN
                raise ValueError(f"--segmenter-scale must be a number in [{MIN_SCALE:g}, {MAX_SCALE:g}], got "
                                 f"{args.segmenter_scale!r}")
        name, noise_model = None, None
        if kind == "noisy":  # the given model, else the task's own loop tracker's
            from dyndlo_vision.tasks import noise as noise_models

            name = args.obs_noise or noise_models.task_noise_model(task)
            noise_model = noise_models.ObservationNoiseModel.load(
                noise_models.noise_model_file(noise_models.resolve_noise_model_path(name)))
        return cls(kind, name, noise_model, args.segmenter, args.segmenter_model, args.segmenter_scale,
                   args.views, float(args.latency_ms))

    def perception(self, env: Any, task: str) -> LoopPerception | None:
        """How the loop sees the cable in ``env``'s scene (None unless tracked): the scene's defaults where no
        option was given.

        Raises:
            ValueError: The scene has fewer cameras than ``--views``, or its own segmenter is not the learned
                one that ``--segmenter-model`` or ``--segmenter-scale`` is for.
        """
        if self.kind != "tracked":
            return None
        from dyndlo_vision.control.sim_perception import (
            LoopPerception,
            default_segmenter,
            loop_segmenter,
            scene_views,
        )

        available = scene_views(env)
        views = available if self.views is None else self.views
        if views > available:
            raise ValueError(f"--views {views}: the {task} scene has one tracking camera; expected --views 1")
        segmenter = self.segmenter or default_segmenter(env)
        if segmenter != "learned" and (self.segmenter_model is not None or self.segmenter_scale is not None):
            raise ValueError(f"--segmenter-model and --segmenter-scale are for --segmenter learned; the "
                             f"{task} scene's default segmenter is {segmenter!r}")
        return LoopPerception(loop_segmenter(segmenter, self.segmenter_model, self.segmenter_scale), views,
                              latency_s=1e-3 * self.latency_ms)
