"""Known effects injected into the measured recordings of ../shared/data, diagnosed before and after.

    python experiments/diagnosis_injection.py [--only NAME ...] [--kinds offset,followed,drift,bias]
                                              [--seed 0] [--json FILE] [--markdown FILE]

Each recording goes through its link map and calibration (experiments/diagnose_measured.py) and is
diagnosed with Human48 as it is; then each injection is made alone, at the link level, and the
recording diagnosed again:

- offset: a segment's frame turned by 10-15 deg about an axis its joints cannot follow (a shank about
  its forward axis, which Human48's knee lacks; in the upper-body MVNX file, a forearm about its own x,
  which the elbow lacks). It must come back as a misalignment of that segment, within 2 deg of its size
  in the directions the data determine, with no new effect elsewhere; or, where the data tell that turn
  from a neighbour's only poorly (a shank's and a thigh's about the knee's missing axis: the knee
  cannot turn one against the other about it, so the data see their difference), the report must say
  so (its list of turns two neighbouring sensors leave nearly the same residual for), with nothing new
  but a misalignment of one of the two. Its size is measured against the
  segment's own offset in the recording as it was (the misalignment the first diagnosis kept there, or
  else what the misalignment family fits there at its end, significant or not): a measured segment
  frame is never exactly the model's, and the injection turns it further.
- followed: the same segment turned about an axis its joints follow (a shank about its long axis, the
  knee's rotation; a forearm about its long axis, the elbow's pronation): nothing can be seen, and the
  report must say so (its list of turns the data cannot see names that link and direction).
- drift: a segment's heading drifting at 1-2 deg/s about the vertical (a thigh; an upper arm in the
  MVNX file): where the angular velocity is derived from the orientations, it is derived again from the
  drifting ones; where the file has gyros, they are turned with the orientations (a heading reference
  moved under an unbiased gyro). It must come back as a heading drift of that segment.
- bias: a gyro bias of 1.5-3 deg/s in a random direction, only where the file has gyros (MVNX).

Scored: the effects kept (kind and link) that the injected run has and the first had not (new) and the
reverse (gone); named when the injected effect is kept on its link (the first run may have kept one
there already, for the segment's own offset) and nothing else is new.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from diagnose_measured import DATA, SOURCES, Source, recording_of

from torchik.io.recording import angular_velocity_from_orientations
from torchik.method import so3
from torchik.method.kinematics import KinematicModel
from torchik.method.models import TRACKED_LINKS, human_urdf
from torchik.pipelines.diagnosis.candidates import candidates
from torchik.pipelines.diagnosis.effect import halves, replace, rotation_about
from torchik.pipelines.diagnosis.loop import Diagnosis, diagnose
from torchik.pipelines.diagnosis.streams import derived_rates

KINDS = ("offset", "followed", "drift", "bias")
WITHIN = 2.0  # deg: an offset named within this of its size
DEG = math.pi / 180


@dataclass
class Injection:
    """One injection: kind, link, the link-frame axis (offset) or rate (drift) or bias, its size."""

    kind: str
    link: str
    size: float
    unit: str
    axis: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def describe(self) -> str:
        if self.kind in ("offset", "followed"):
            return f"{self.link} frame turned {self.size:.1f} deg about {tuple(round(a, 2) for a in self.axis)}"
        if self.kind == "drift":
            return f"{self.link} heading drifting {self.size:+.2f} deg/s"
        return f"{self.link} gyro biased {self.size:.2f} deg/s along {tuple(round(a, 2) for a in self.axis)}"


def moving(recording, links) -> set[str]:
    """The links whose orientation changes by more than 5 deg over the recording (a leg of the upper-body
    MVNX file repeats the pelvis and does not move on its own)."""
    base = recording.links.index(recording.base_link)
    out = set()
    for name in links:
        i = recording.links.index(name)
        rel = np.einsum("tji,tjk->tik", recording.orientation[:, base], recording.orientation[:, i])
        ok = np.isfinite(rel).all((1, 2))
        angles = so3.log(torch.from_numpy(rel[ok][:, None] @ np.swapaxes(rel[ok][:1], 1, 2))).norm(dim=-1)
        if len(angles) and float(angles.max()) > 5 * DEG:
            out.add(name)
    return out


def injections(source: Source, recording, links, gyros: bool, rng: np.random.Generator, kinds) -> list[Injection]:
    """The injections of one recording (module docstring), their sizes drawn from rng."""
    legs = {"RightLowerLeg", "LeftLowerLeg"} & moving(recording, links)
    side = str(rng.choice(sorted(legs))) if legs else ""
    segment = side or str(rng.choice(["LeftForeArm", "RightForeArm"]))
    out = []
    if "offset" in kinds:
        out.append(Injection("offset", segment, float(rng.uniform(10, 15)), "deg", (1.0, 0.0, 0.0)))
    if "followed" in kinds:
        out.append(Injection("followed", segment, float(rng.uniform(10, 15)), "deg", (0.0, 0.0, 1.0)))
    if "drift" in kinds:
        upper = segment.replace("LowerLeg", "UpperLeg").replace("ForeArm", "UpperArm")
        out.append(Injection("drift", upper, float(rng.choice([-1, 1]) * rng.uniform(1, 2)), "deg/s"))
    if "bias" in kinds and gyros:
        axis = rng.normal(size=3)
        out.append(Injection("bias", segment, float(rng.uniform(1.5, 3)), "deg/s", tuple(axis / np.linalg.norm(axis))))
    return out


def inject(recording, injection: Injection, gyros: bool):
    """The recording with the injection made (module docstring)."""
    i = recording.links.index(injection.link)
    R, w = recording.orientation.copy(), recording.angular_velocity.copy()
    if injection.kind in ("offset", "followed"):
        R[:, i] = R[:, i] @ rotation_about(injection.axis, np.array([injection.size * DEG]))[0]
    elif injection.kind == "drift":
        Rz = rotation_about([0.0, 0.0, 1.0], injection.size * DEG * (recording.time - recording.time[0]))
        R[:, i] = Rz @ R[:, i]
        w[:, i] = (Rz @ w[:, i, :, None])[..., 0] if gyros else angular_velocity_from_orientations(
            R[:, i:i + 1], recording.time)[:, 0]
    else:
        w[:, i] += recording.orientation[:, i] @ (np.asarray(injection.axis) * injection.size * DEG)
    return replace(recording, orientation=R, angular_velocity=w)


def kept(d: Diagnosis) -> set[tuple[str, str]]:
    return {(e.kind, e.target) for e in d.effects}


def baseline_offset(d: Diagnosis, link: str) -> np.ndarray:
    """[3] the link's own offset in the recording as it was: the misalignment the diagnosis kept there,
    or what the misalignment family fits there on its last analysis (significant or not)."""
    for e in d.effects:
        if e.kind == "misalignment" and e.target == link:
            return np.asarray(e.params["rotation_vector"], dtype=np.float64)
    analysis, b = d.last
    train, test = halves(analysis.time)
    fits = [c for c in candidates(analysis, b, train, test, d.urdf, ("misalignment",), target=link) if c.fit is not None]
    return np.asarray(fits[0].params["rotation_vector"], dtype=np.float64) if fits else np.zeros(3)


def judge(injection: Injection, before: Diagnosis, after: Diagnosis) -> dict:
    """Whether the injection was named (module docstring) and with what size."""
    new, gone = sorted(kept(after) - kept(before)), sorted(kept(before) - kept(after))
    want = {"offset": "misalignment", "drift": "heading_drift", "bias": "gyro_bias"}.get(injection.kind)
    out: dict = dict(new=[f"{k} at {t}" for k, t in new], gone=[f"{k} at {t}" for k, t in gone])
    if injection.kind == "followed":
        hidden = np.asarray(after.unseen.get(injection.link, []), dtype=np.float64).reshape(-1, 3)
        said = bool(len(hidden)) and float(np.linalg.norm(hidden @ np.asarray(injection.axis))) > math.cos(20 * DEG)
        out.update(named=not new and said, said_unseen=said)
        return out
    found = [e for e in after.effects if e.kind == want and e.target == injection.link]
    # named as what it is on its link (kept there before too, where the recording's own offset was), and
    # nothing new anywhere else
    out["named"] = bool(found) and set(new) <= {(want, injection.link)}
    if injection.kind == "offset":  # or said to be a turn the data cannot tell from a neighbour's
        told = [c for c in after.confounded.get(injection.link, [])
                if abs(float(np.dot(c["direction"], injection.axis))) > math.cos(30 * DEG)]
        out["confounded_with"] = sorted({c["neighbour"] for c in told})
        allowed = {(want, injection.link)} | {(want, n) for n in out["confounded_with"]}
        out["said_confounded"] = bool(told) and set(new) <= allowed
    if not found:
        out["named"] = out.get("said_confounded", False)
        return out
    e = found[0]
    if injection.kind == "offset":
        C_base = so3.exp(torch.from_numpy(baseline_offset(before, injection.link)))
        C_found = so3.exp(torch.tensor(e.params["rotation_vector"], dtype=torch.float64))
        estimate = so3.log(C_base.T @ C_found).numpy()
        truth = np.asarray(injection.axis) * injection.size * DEG
        V = np.asarray(e.params.get("identified", np.eye(3)), dtype=np.float64).reshape(-1, 3)
        error = float(np.degrees(np.linalg.norm(V @ (estimate - truth))))
        out.update(found=float(np.degrees(np.linalg.norm(estimate))), error_deg=error)
        out["named"] = (out["named"] and error <= WITHIN) or out["said_confounded"]
    elif injection.kind == "drift":
        out.update(found=float(np.degrees(e.params["rate"])), variant="gyro shares" if e.params.get("gyro_shares") else
                   "gyro unaware")
    else:
        out.update(found=float(np.degrees(np.linalg.norm(e.params["bias"]))))
    return out


def run(source: Source, kinds, seed: int, say) -> list[dict]:
    urdf = human_urdf(48)
    model = KinematicModel.from_urdf(urdf, name="Human48")
    recording = recording_of(source, model)
    links = [name for name in TRACKED_LINKS["human48"] if name in recording.links]
    ids = [recording.links.index(n) for n in links]
    gyros = not bool(derived_rates(torch.from_numpy(recording.orientation[:, ids]),
                                   torch.from_numpy(recording.angular_velocity[:, ids]),
                                   torch.from_numpy(recording.time)).all())
    rng = np.random.default_rng(seed + SOURCES.index(source))

    def diagnosed(rec) -> tuple[Diagnosis, float]:
        start = time.perf_counter()
        d, = diagnose(model, urdf, [rec], links, max_effects=10)
        return d, time.perf_counter() - start

    before, seconds = diagnosed(recording)
    say(f"{source.name}: as it is, {len(before.effects)} effects kept ({seconds:.0f} s)")
    rows = []
    for injection in injections(source, recording, links, gyros, rng, kinds):
        after, seconds = diagnosed(inject(recording, injection, gyros))
        row = dict(recording=source.name, injection=injection.kind, link=injection.link, size=injection.size,
                   unit=injection.unit, what=injection.describe(), seconds=seconds, **judge(injection, before, after))
        found = f", found {row['found']:.2f}" if "found" in row else ""
        say(f"    {injection.describe()}: {'named' if row['named'] else 'NOT named'}{found}; new {row['new'] or 'none'}; "
            f"gone {row['gone'] or 'none'} ({seconds:.0f} s)")
        rows.append(row)
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| recording | injected | named | found | new effects | effects gone |", "|---|---|---|---|---|---|"]
    for r in rows:
        found = ("-" if "found" not in r else f"{r['found']:.2f}" + (f" (error {r['error_deg']:.2f} deg)"
                                                                       if "error_deg" in r else ""))
        if r["injection"] == "followed":
            found = "said not identifiable" if r.get("said_unseen") else "NOT said"
        elif r.get("said_confounded") and not r.get("error_deg", math.inf) <= WITHIN:
            found = f"said to be told from {', '.join(r['confounded_with'])}'s only poorly" + (
                f"; {found}" if found != "-" else "")
        lines.append(f"| {r['recording']} | {r['what']} | {'yes' if r['named'] else '**no**'} | {found} | "
                     f"{', '.join(r['new']) or '-'} | {', '.join(r['gone']) or '-'} |")
    by = {}
    for r in rows:
        by.setdefault(r["injection"], []).append(r["named"])
    lines += ["", "| injected | named as such, nothing new elsewhere |", "|---|---|"]
    lines += [f"| {k} | {sum(v)} of {len(v)} |" for k, v in by.items()]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", nargs="*", help="recordings to run (names as in diagnose_measured.py)")
    parser.add_argument("--kinds", default=",".join(KINDS), help=f"injections, comma-separated (default {','.join(KINDS)})")
    parser.add_argument("--seed", type=int, default=0, help="the sizes' and sides' seed (default 0)")
    parser.add_argument("--json", help="write the rows as JSON")
    parser.add_argument("--markdown", help="write the table as markdown")
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        print(f"{DATA}: no measured data here; nothing to do")
        return 1
    torch.set_num_threads(1)
    kinds = tuple(k for k in args.kinds.split(",") if k)
    rows = []
    for source in SOURCES:
        if args.only and source.name not in args.only:
            continue
        rows += run(source, kinds, args.seed, lambda line: print(line, flush=True))
    table = markdown(rows)
    print(table)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=float) + "\n")
    if args.markdown:
        Path(args.markdown).write_text(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
