"""``kgnav eval``, ``kgnav memory-map`` and ``kgnav goal-floors``: the ObjectNav benchmark from
the command line (see :mod:`kgnav.benchmark.runner`), the memories a run left, drawn over its
houses, and the confidence floors for remembered goals calibrated on them."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import click
import numpy as np
from rich.console import Console
from rich.table import Table

from kgnav.agent.loop import MEMORY_GOAL_REASONS
from kgnav.agent.noise_segmenters import SEGMENTER_PRESETS
from kgnav.agent.relocation import HYPOTHESIS_OUTCOMES
from kgnav.benchmark.engines import ENGINES
from kgnav.benchmark.failures import FAILURE_CLASSES
from kgnav.benchmark.variants import VARIANTS
from kgnav.cli._output import safe, wide_console
from kgnav.errors import KgnavError
from kgnav.sim.episodes import SPLITS

_ABBREV = {"Last Mile": "LM", "Hallucination": "Hal", "Detection": "Det",
           "Exploration": "Exp", "Misc": "Misc"}
_REASONS = {"not_relocated": "not relocated", "relocated_too_late": "too late",
            "goal_seen_in_episode": "seen first", "live_detection_preferred": "own preferred",
            "goal_in_other_model": "other model", "belief_below_threshold": "low belief",
            "goal_not_in_relocated_model": "not in model", "other": "other"}


def _variants(ctx, param, value: str) -> tuple[str, ...]:
    names = tuple(dict.fromkeys(v.strip() for v in value.split(",") if v.strip()))
    if not names:
        raise click.BadParameter("give at least one variant", ctx, param)
    bad = [n for n in names if n not in VARIANTS]
    if bad:
        raise click.BadParameter(f"unknown variant {bad[0]!r} (known: {', '.join(VARIANTS)})",
                                 ctx, param)
    return names


def _show(ctx, param, value: str | None) -> tuple[int, int] | None:
    if value is None:
        return None
    try:
        scene, ep = (int(v) for v in value.split(":"))
    except ValueError:
        raise click.BadParameter(f"expected SCENE:EPISODE (two integers), got {value!r}",
                                 ctx, param) from None
    return scene, ep


def _settings(config_cls, what: str):
    """A click callback parsing ``KEY=VALUE`` settings of the dataclass ``config_cls`` (its
    plain fields: numbers, switches, names, pairs), each value parsed as the field's default is
    typed (a pair as ``A,B``); ``what`` names them in errors."""
    from dataclasses import fields

    def parse(ctx, param, values: tuple[str, ...]) -> dict:
        known = {f.name: f.default for f in fields(config_cls)
                 if isinstance(f.default, (bool, int, float, str, tuple))
                 or (f.default is None and str(f.type) == "float | None")}
        out: dict = {}
        for item in values:
            key, eq, text = item.partition("=")
            key = key.strip()
            if not eq or not text.strip():
                raise click.BadParameter(f"expected KEY=VALUE, got {item!r}", ctx, param)
            if key not in known:
                raise click.BadParameter(
                    f"unknown {what} setting {key!r} (known: {', '.join(known)})", ctx, param)
            default = known[key]
            # a tuple of (name, number) pairs, empty by default, or a fixed-length tuple of numbers
            pairs = isinstance(default, tuple) and (not default or isinstance(default[0], tuple))
            try:
                if default is None:  # an optional number: "none" turns it off
                    value = None if text.strip().lower() == "none" else float(text)
                elif isinstance(default, bool):
                    value = click.BOOL.convert(text.strip(), param, ctx)
                elif pairs:
                    value = tuple(_pair(v) for v in text.split(","))  # NAME:NUMBER,...
                elif isinstance(default, tuple):
                    value = tuple(float(v) for v in text.split(","))
                    if len(value) != len(default):
                        raise ValueError
                else:
                    value = type(default)(text)
            except (ValueError, click.BadParameter):
                like = ("NAME:NUMBER,..." if pairs else "a number or none" if default is None
                        else repr(default))
                raise click.BadParameter(f"{key} takes a value like {like}, got {text!r}",
                                         ctx, param) from None
            out[key] = value
        return out

    return parse


def _pair(text: str) -> tuple[str, float]:
    name, colon, number = text.partition(":")
    if not colon or not name.strip():
        raise ValueError(text)
    return name.strip(), float(number)


def _relocation(ctx, param, values: tuple[str, ...]) -> dict:
    """``KEY=VALUE`` settings of :class:`~kgnav.agent.relocation.RelocationConfig`."""
    from kgnav.agent.relocation import RelocationConfig

    return _settings(RelocationConfig, "relocation")(ctx, param, values)


def _agent(ctx, param, values: tuple[str, ...]) -> dict:
    """``KEY=VALUE`` settings of :class:`~kgnav.agent.loop.AgentConfig` (its own plain
    fields; relocation and goals have their own options)."""
    from kgnav.agent.loop import AgentConfig

    return _settings(AgentConfig, "agent")(ctx, param, values)


def _goals(ctx, param, values: tuple[str, ...]) -> dict:
    """``KEY=VALUE`` settings of :class:`~kgnav.agent.goals.GoalConfig`."""
    from kgnav.agent.goals import GoalConfig

    return _settings(GoalConfig, "goal")(ctx, param, values)


def _noise(ctx, param, value: str | None) -> str | None:
    """A noise spec (:func:`kgnav.sim.noise.parse_noise`), canonical; None: the default."""
    if value is None:
        return None
    from kgnav.sim.noise import parse_noise

    try:
        return parse_noise(value).text
    except KgnavError as e:
        raise click.BadParameter(str(e), ctx, param) from None


@click.command("eval")
@click.option("--env", "env_name", default="kgnav", show_default=True, metavar="NAME",
              help="The environment: kgnav (the embedded simulator), any registered with "
                   "kgnav.envs.register_env or the 'kgnav.envs' entry points, or "
                   "MODULE:FACTORY.")
@click.option("--split", default="val", show_default=True,
              help=f"Which scenes: for --env kgnav one of {', '.join(SPLITS)} (train/val at "
                   "Matterport3D scale, *-small from the first, small generator); another "
                   "environment's own names otherwise.")
@click.option("--scenes-dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Run your own houses instead of --split: a directory written by "
                   "'kgnav scenes generate'.")
@click.option("--variants", callback=_variants, default="ans", show_default=True,
              help=f"Comma-separated: {', '.join(VARIANTS)}.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("export/eval"), show_default=True,
              help="Where episodes.jsonl, summary.json, plots and memories go.")
@click.option("--scenes", type=click.IntRange(min=1), default=None,
              help="Run only the first K scenes of the split (default: all).")
@click.option("--episodes", type=click.IntRange(min=1), default=None,
              help="Episodes per scene (default: the split's, 100 for val; all of a "
                   "--scenes-dir).")
@click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
              help="Processes (with --engine ray: the CPUs of the Ray instance it starts); "
                   "results are identical to one.")
@click.option("--engine", type=click.Choice(list(ENGINES)), default="local",
              show_default=True,
              help="Where episodes run: local processes, or Ray tasks (pip install "
                   "'kgnav[ray]'); results are identical.")
@click.option("--address", default=None, metavar="ADDR",
              help="With --engine ray: join the Ray cluster at ADDR (HOST:PORT, 'auto' or "
                   "ray://HOST:PORT) instead of starting Ray here.")
@click.option("--segmenter", type=click.Choice(["learned", *sorted(SEGMENTER_PRESETS)]),
              default="learned", show_default=True,
              help="learned: the RGB-D network; or a noise preset on ground truth ('clean').")
@click.option("--segmenter-weights", type=click.Path(dir_okay=False, path_type=Path),
              default=None, metavar="FILE",
              help="Weights of the learned segmenter [default: the shipped ones, trained on "
                   "kgnav's simulator], e.g. trained on another environment's frames "
                   "(train-segmenter --env).")
@click.option("--allow-domain-mismatch", is_flag=True,
              help="Run learned segmenter or encoder weights trained on another environment "
                   "than --env (refused otherwise: they see another visual domain).")
@click.option("--extractor", default="auto", show_default=True,
              help="State features: kgnav-encoder, opencv-gist, or auto (the encoder if it "
                   "loads).")
@click.option("--threshold", type=click.FloatRange(0.0, 2.0), default=None,
              help="Relocation cosine-distance threshold (default: the extractor's loop "
                   "one).")
@click.option("--encoder-weights", type=click.Path(dir_okay=False, path_type=Path),
              default=None, metavar="FILE",
              help="Weights of kgnav-encoder [default: the shipped ones], e.g. retrained on "
                   "another environment's frames (train-encoder --env); its models are named "
                   "kgnav-encoder:<fingerprint> and never mix with the shipped encoder's.")
@click.option("--pre-explore-steps", type=click.IntRange(min=10), default=1500,
              show_default=True, help="Budget of the hp/sp pre-exploration per house.")
@click.option("--show", callback=_show, default=None, metavar="SCENE:EPISODE",
              help="Draw this episode from above for every variant (default: 0:LAST).")
@click.option("--noise", callback=_noise, default=None, metavar="SPEC",
              help="Motion, pose-sensor and depth noise: locobot (the default: a LoCoBot's "
                   "motion, fitted on the real robot as in habitat-sim, and wheel odometry that "
                   "drifts with distance; none with --preset paper), with optional ,scale=K "
                   "(every noise times K), ,slip=F (share of a bump's blocked length the "
                   "odometry reports; 0: a base with a bumper) and ,depth=S (S m of depth "
                   "noise per metre); or actuation=K,odometry=S (K scales Gaussian 2.5 cm / 1 cm / "
                   "1 deg per move and 2 deg per turn; S m and S deg of pose error per step); "
                   "or none (the noise-free ObjectNav task). See docs/benchmark.md.")
@click.option("--drift-correction/--no-drift-correction", default=True, show_default=True,
              help="With a drifting pose sensor (--noise), bend each episode onto the model it "
                   "merges into by its loop closures (a GTSAM pose graph; docs/drift.md).")
@click.option("--consolidate/--no-consolidate", default=None,
              help="After each round, join stored models that verifiably fit each other as a "
                   "whole: one memory per house (default: on; off with --preset paper).")
@click.option("--preset", type=click.Choice(["default", "paper"]), default="default",
              show_default=True,
              help="Agent settings: default (verified relocation, remembered geometry, "
                   "evidence-weighted goals, close-range confirmation, memory consolidation) "
                   "or the paper's own (and its noise-free task unless --noise says).")
@click.option("--policy", default=None, metavar="NAME",
              help="Global exploration policy of ans and si: frontier (their default), ppo, "
                   "ppo-semantic, random-goal, ...; sem+si keeps semantic unless "
                   "ppo-semantic.")
@click.option("--relocation", "relocation", multiple=True, callback=_relocation,
              metavar="KEY=VALUE",
              help="Change one setting of the preset's relocation (RelocationConfig, "
                   "docs/memory.md), e.g. bare_inliers=0 or absence_views=0; repeatable. "
                   "Recorded in config.json.")
@click.option("--agent", "agent_settings", multiple=True, callback=_agent,
              metavar="KEY=VALUE",
              help="Change one setting of the preset's agent (AgentConfig, docs/agent.md), "
                   "e.g. prior_inflation=0.1 or detour_ratio=3; repeatable. Recorded in "
                   "config.json.")
@click.option("--goals", "goals", multiple=True, callback=_goals, metavar="KEY=VALUE",
              help="Change one setting of the preset's choice of a remembered goal "
                   "(GoalConfig, docs/agent.md), e.g. min_score=0.72; repeatable. Recorded "
                   "in config.json.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--store", "store", type=click.Choice(["directory", "ladybug"]),
              default="directory", show_default=True,
              help="Where the memory is written: OUT/memory/VARIANT/ as GraphML files, or the "
                   "graph database OUT/memory/VARIANT.lbug (kgnav[graphdb]); the results are "
                   "the same.")
@click.option("--quiet", is_flag=True, help="No progress bars.")
def eval_cmd(env_name, split, scenes_dir, variants, out_dir, scenes, episodes, workers, engine,
             address, segmenter, segmenter_weights, allow_domain_mismatch, extractor, threshold,
             encoder_weights, pre_explore_steps, show, noise, drift_correction, consolidate, preset,
             policy, relocation, agent_settings, goals, seed, store, quiet) -> None:
    """Run agent variants over a split; write episodes.jsonl, summary.json and plots."""
    from kgnav.agent.loop import PRESETS
    from kgnav.agent.policy import make_policy, policy_names
    from kgnav.envs import find_env

    try:
        find_env(env_name)
    except KgnavError as e:
        raise click.BadParameter(str(e), param_hint="--env") from None
    if env_name == "kgnav" and scenes_dir is None and split not in SPLITS:
        raise click.BadParameter(f"unknown split {split!r} (known: {', '.join(SPLITS)})",
                                 param_hint="--split")

    if policy is not None:
        if policy not in policy_names():
            raise click.BadParameter(f"unknown policy {policy!r} (known: "
                                     f"{', '.join(policy_names())})", param_hint="--policy")
        make_policy(policy)  # a weight file that does not load fails here, in one line
    if encoder_weights is not None:
        if extractor not in ("auto", "kgnav-encoder"):
            raise click.BadParameter(f"weights of kgnav-encoder, but --extractor is "
                                     f"{extractor!r}", param_hint="--encoder-weights")
        from kgnav.nets.encoder.weights import load_weights

        load_weights(encoder_weights)  # one line, exit 1, when the file does not load
    if segmenter_weights is not None:
        if segmenter != "learned":
            raise click.BadParameter(f"weights of the learned segmenter, but --segmenter is "
                                     f"{segmenter!r}", param_hint="--segmenter-weights")
        from kgnav.nets.segnet.weights import load_weights as load_segmenter

        load_segmenter(segmenter_weights)  # one line, exit 1, when the file does not load
    from kgnav.benchmark.runner import EvalConfig, run_eval

    agent = PRESETS[preset]()
    if agent_settings:
        try:
            agent = replace(agent, **agent_settings)
        except ValueError as exc:  # a value of the right type that AgentConfig refuses
            raise click.BadParameter(str(exc), param_hint="--agent") from None
    if relocation:
        try:
            agent = replace(agent, relocation=replace(agent.relocation, **relocation))
        except ValueError as exc:  # a value of the right type that RelocationConfig refuses
            raise click.BadParameter(str(exc), param_hint="--relocation") from None
    if goals:
        try:
            agent = replace(agent, goals=replace(agent.goals, **goals))
        except ValueError as exc:  # values each fine alone, refused by GoalConfig together
            raise click.BadParameter(str(exc), param_hint="--goals") from None
    cfg = EvalConfig(split=split, scenes_dir=None if scenes_dir is None else str(scenes_dir),
                     variants=variants, scenes=scenes, episodes=episodes,
                     workers=workers, engine=engine, address=address, segmenter=segmenter,
                     extractor=extractor, threshold=threshold, seed=seed,
                     pre_explore_steps=pre_explore_steps,
                     show=show, drift_correction=drift_correction,
                     noise="none" if noise is None and preset == "paper" else noise,
                     consolidate=(preset == "default") if consolidate is None else consolidate,
                     agent=agent, forget_below=0.2 if preset == "default" else 0.0,
                     forget_label_share=0.5 if preset == "default" else 0.0,
                     preset=preset, policy=policy, env=env_name,
                     encoder_weights=None if encoder_weights is None else str(encoder_weights),
                     segmenter_weights=None if segmenter_weights is None
                     else str(segmenter_weights),
                     allow_domain_mismatch=allow_domain_mismatch, store=store)
    if show is None:  # the first house's last episode
        cfg = replace(cfg, show=(0, cfg.suite.episode_count(0, episodes) - 1))
    _records, summary = run_eval(cfg, out_dir, progress=not quiet)
    print_summary(summary)
    click.echo(f"wrote {out_dir / 'episodes.jsonl'}, {out_dir / 'summary.json'} and plots")


def print_summary(summary: dict) -> None:
    """The paper's Table 1/3 analogue, plus relocation and failure counts."""
    table = Table("variant", "episodes", "Success", "SPL", "SoftSPL", "DTS (m)", "relocated",
                  *(_ABBREV[c] for c in FAILURE_CLASSES), "ep/s",
                  title="ObjectNav (failures: Last Mile, Hallucination, Detection, "
                        "Exploration, Misc)")
    for name, s in summary.items():
        table.add_row(
            name, str(s["episodes"]), f"{s['success']:.3f}", _f(s["spl"], 3),
            _f(s["softspl"], 3), _f(s["dts"], 3), f"{s['relocation_rate']:.2f}",
            *(str(s["failures"][c]) for c in FAILURE_CLASSES),
            f"{s['episodes_per_second']:.2f}" if s.get("episodes_per_second") else "",
        )
    console = wide_console()
    console.print(table)
    paired = {n: s["vs_ans"] for n, s in summary.items() if "vs_ans" in s}
    if paired:
        t2 = Table("variant", "pairs", "Success − ans [95 % CI]", "SPL − ans [95 % CI]",
                   title="Paired difference against ans (same episodes; bootstrap interval)")
        for name, d in paired.items():
            t2.add_row(name, str(d["success"]["pairs"]),
                       *(f"{d[m]['diff']:+.3f} [{d[m]['low']:+.3f}, {d[m]['high']:+.3f}]"
                         for m in ("success", "spl")))
        console.print(t2)
    mem = {n: s for n, s in summary.items() if "memory" in s}
    if mem:
        t3 = Table("variant", "reloc. after 1st (min/mean)", "reloc. step",
                   "reloc. err. m: made / tracking (vs stored)",
                   "wrong merges (bridges, joins; merges vs stored)",
                   "models/house", "objects", "precision (trusted)", "copies", "recall",
                   "pose err. m, heading ° (median / p95)",
                   "own frame: precision / recall (frames off m, median / max)",
                   title="Relocation and memory fidelity (against ground truth)")
        for name, s in mem.items():
            p = s["memory"]["pooled"]
            lo, mean = s.get("relocated_after_first_min"), s.get("relocated_after_first_mean")
            t3.add_row(
                name, "–" if lo is None else f"{lo:.2f} / {mean:.2f}",
                "–" if s.get("relocation_step") is None else f"{s['relocation_step']:.0f}",
                f"{_f(s.get('relocation_error_m'))} / {_f(s.get('relocation_tracking_m'))} "
                f"({_f(s.get('relocation_local_m'))} / "
                f"{_f(s.get('relocation_tracking_local_m'))})",
                f"{s.get('wrong_merges', 0)} ({s.get('wrong_bridges', 0)}, "
                f"{s.get('wrong_joins', 0)} of {s.get('joins', 0)}; "
                f"{s.get('wrong_merges_local', 0)})",
                " ".join(f"{k}:{v}" for k, v in p["models_per_house"].items()),
                str(p["objects"]), f"{_f(p['precision'])} ({_f(p['trusted_precision'])})",
                _f(p["copies"]), _f(p["recall"]),
                _pose_error(p.get("pose_error_m"), p.get("heading_error_deg")),
                _own_frame(p))
        console.print(t3)
    _print_where_lost(console, summary)
    _print_hypotheses(console, summary)


def _print_where_lost(console: Console, summary: dict) -> None:
    """Where a memory variant's success is lost: episodes whose memory held the goal against
    those whose memory did not (that part paired with ans), why goal-in-memory episodes did
    not head for the remembered goal, and every variant's success by a house's episode
    index."""
    lost = {n: s for n, s in summary.items() if "goal_in_memory" in s}
    if lost:
        t = Table("variant", "in memory: n", "Success / SPL", "not in memory: n",
                  "Success / SPL", "Success − ans [95 % CI] (pairs)",
                  title="Where success is lost (goal in memory: a stored model of the house "
                        "held a true instance as the episode started)")
        for name, s in lost.items():
            held, missing = s["goal_in_memory"], s["goal_not_in_memory"]
            d = s.get("goal_not_in_memory_vs_ans", {}).get("success")
            t.add_row(name, str(held["episodes"]),
                      f"{_f(held['success'], 3)} / {_f(held['spl'], 3)}",
                      str(missing["episodes"]),
                      f"{_f(missing['success'], 3)} / {_f(missing['spl'], 3)}",
                      "–" if d is None or d["diff"] is None
                      else f"{d['diff']:+.3f} [{d['low']:+.3f}, {d['high']:+.3f}] ({d['pairs']})")
        console.print(t)
        t2 = Table("variant", "headed", *(_REASONS[r] for r in MEMORY_GOAL_REASONS),
                   title="Goal in memory: episodes that headed for the remembered goal, and "
                         "why the others did not")
        for name, s in lost.items():
            t2.add_row(name, str(s["memory_goal_headed"]),
                       *(str(s["memory_goal_reasons"][r]) for r in MEMORY_GOAL_REASONS))
        console.print(t2)
        for name, s in lost.items():
            a, b = s.get("goal_not_in_memory_seen_before"), s.get("goal_not_in_memory_never_seen")
            e = s.get("exploration_failures_goal_in_view")
            if a is None or b is None or e is None:
                continue  # (a summary written before these were scored)
            console.print(
                f"{name}: goal not in memory, though an earlier episode of the house had it "
                f"in view: {a['episodes']} (success {_f(a['success'], 3)}); never in view: "
                f"{b['episodes']} (success {_f(b['success'], 3)}). Exploration failures "
                f"whose goal came into view unrecognised: {e['in_view']} of {e['episodes']}")
    curves = {n: s for n, s in summary.items() if "success_by_episode_index" in s}
    if curves:
        t3 = Table("variant", "Success by episode index in a house (0: its first)",
                   "from the 5th on", title="Learning curve")
        for name, s in curves.items():
            curve = s["success_by_episode_index"]
            shown = " ".join(f"{v:.2f}" for v in curve[:10])
            t3.add_row(name, shown + (f" … ({len(curve)})" if len(curve) > 10 else ""),
                       _f(s["success_from_fifth_episode"], 3))
        console.print(t3)


def _pose_error(e: dict | None, heading: dict | None = None) -> str:
    """The stored states' pose error (fidelity.error_summary): median / p95 m, then their
    headings' median / p95 in degrees when known, (states)."""
    if not e or e.get("median") is None:
        return "–"
    h = ("" if not heading or heading.get("median") is None
         else f", {heading['median']:.1f} / {heading['p95']:.1f}°")
    return f"{e['median']:.3f} / {e['p95']:.3f}{h} ({e['states']})"


def _own_frame(p: dict) -> str:
    """The memory scored in each model's own frame, and how far the start frames are off
    (summaries written before these were scored have neither: a dash)."""
    own, off = p.get("own_frame"), p.get("frame_error_m")
    if not own:
        return "–"
    far = "" if not off or off.get("median") is None else \
        f" ({off['median']:.2f} / {off['max']:.2f})"
    return f"{_f(own['precision'])} / {_f(own['recall'])}{far}"


def _print_hypotheses(console: Console, summary: dict) -> None:
    """The relocation hypotheses a memory variant's loop judged, by truth and outcome, and
    whether the episodes that never relocated were offered the right place."""
    from kgnav.benchmark.runner import OVERLAP_RADIUS

    rows = {n: s["hypotheses"] for n, s in summary.items() if "hypotheses" in s}
    if not rows:
        return
    t = Table("variant", "truth", *HYPOTHESIS_OUTCOMES,
              title="Relocation hypotheses judged in the loop, against ground truth (right: "
                    "this house, within 1 m and 30°)")
    for name, h in rows.items():
        for truth, counts in h["judged"].items():
            t.add_row(name, truth.replace("_", " "),
                      *(str(counts.get(o, 0)) for o in HYPOTHESIS_OUTCOMES))
    console.print(t)
    for name, h in rows.items():
        console.print(f"{name}: {h['not_relocated']} episodes never relocated though the "
                      "memory held their house; "
                      f"{h['not_relocated_offered_right']} of them were offered the right "
                      f"place ({h['not_relocated_refused_geometry']} refused it for its "
                      "geometry alone); they walked a median "
                      f"{_f(h.get('not_relocated_overlap'))} of their steps within "
                      f"{OVERLAP_RADIUS:g} m of a stored state")


def _f(v, digits: int = 2) -> str:
    """A number, or a dash where it is missing (no ground truth for it)."""
    return "–" if v is None else f"{v:.{digits}f}"


@click.command("memory-map")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--variant", default="si", show_default=True,
              help="Whose memory: si, sem+si, or pre-explored (the hp/sp memory).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=None, help="Where the PNGs go [default: RUN_DIR/memory].")
@click.option("--ppm", type=click.FloatRange(min=2, max=200), default=30.0, show_default=True,
              help="Pixels per metre.")
@click.option("--frame", type=click.Choice(["own", "start"]), default="own", show_default=True,
              help="Place each model in its own frame (fitted to where its states truly "
                   "were) or in the start frame of the episode that created it.")
def memory_map(run_dir: Path, variant: str, out_dir: Path | None, ppm: float,
               frame: str) -> None:
    """Draw every object the memory of a `kgnav eval` run holds, house by house, over the
    house from above: colour per model, disc for a real object, cross for a phantom."""
    from kgnav.benchmark.memory_map import draw_run

    for path in draw_run(run_dir, variant, out_dir, ppm, frame):
        click.echo(str(path))


@click.command("goal-floors")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--variant", default="si", show_default=True,
              help="Whose memory: si, sem+si, or pre-explored (the hp/sp memory).")
@click.option("--quantile", type=click.FloatRange(0.0, 0.5), default=0.1, show_default=True,
              help="The share of a class's real objects a floor may leave out.")
@click.option("--min-views", type=click.IntRange(min=1), default=3, show_default=True,
              help="Judge objects seen from at least this many states (goals.score_views).")
@click.option("--frame", type=click.Choice(["own", "start"]), default="own", show_default=True,
              help="Place each model in its own frame (fitted to where its states truly "
                   "were) or in the start frame of the episode that created it.")
@click.option("--json", "as_json", is_flag=True, help="Print the table and floors as JSON.")
def goal_floors(run_dir: Path, variant: str, quantile: float, min_views: int, frame: str,
                as_json: bool) -> None:
    """Calibrate goals.remembered_floor on a `kgnav eval` run's memory: the mean detection
    confidence of its real objects and of its phantoms, by class (ground truth), and for each
    class where the two separate, the floor that leaves out at most QUANTILE of the real ones.
    Calibrate on a noise-free run of train houses; pass the result to `kgnav eval --goals`."""
    from kgnav.benchmark import fidelity
    from kgnav.benchmark.memory_map import run_memory

    stats: dict = {}
    for scene, framed in run_memory(run_dir, variant, frame):
        part = fidelity.confidence_by_class([(m, f) for _, m, f in framed], scene.objects,
                                            min_views)
        for cls, d in part.items():
            mine = stats.setdefault(cls, {"real": [], "phantom": []})
            mine["real"] += d["real"]
            mine["phantom"] += d["phantom"]
    floors = fidelity.suggest_floors(stats, quantile)
    setting = "remembered_floor=" + ",".join(f"{c}:{v:.2f}" for c, v in floors.items())
    if as_json:
        click.echo(json.dumps({"classes": {
            c: {k: {"n": len(v), "median": float(np.median(v)) if v else None,
                    "quantile": float(np.quantile(v, quantile)) if v else None}
                for k, v in d.items()} for c, d in sorted(stats.items())},
            "floors": floors}, indent=2))
        return
    table = Table(title=f"Mean detection confidence of stored objects seen from {min_views}+ "
                        f"states ({variant})")
    for col in ("class", "real: n", f"q{quantile:g}", "median", "phantoms: n", "median",
                "floor"):
        table.add_column(col)
    for cls, d in sorted(stats.items()):  # class names come from the model files: as text
        r, p = d["real"], d["phantom"]
        table.add_row(safe(cls), str(len(r)), _f(float(np.quantile(r, quantile)) if r else None),
                      _f(float(np.median(r)) if r else None), str(len(p)),
                      _f(float(np.median(p)) if p else None), _f(floors.get(cls)))
    wide_console(markup=False).print(table)
    click.echo(f"--goals {safe(setting)}" if floors else "no class separates real objects from "
               "phantoms: no floor to set")
