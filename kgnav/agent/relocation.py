"""Relocation: recognising a stored model while exploring, as hypotheses that must be verified.

The paper relocates on the first stored state whose features lie within the threshold and
merges into its model. A feature match alone is a hypothesis: look-alike rooms in another house,
or the same room turned round (a "rotated twin"), match too, and a wrong merge damages every
later episode in that house. :class:`Relocalizer` therefore

1. **proposes** hypotheses each step from the ``top_k`` stored states nearest in feature space
   (within the threshold), each giving a frame transform ``T`` (episode → model), and, with
   ``scan_search``, from where the recent range profiles fit the models the views looked most
   like (:mod:`kgnav.agent.scan_search`): those must fit as a room fits itself
   (``search_inliers``), since a room of the same shape elsewhere fits nearly as well;
2. **verifies** each against geometry (:meth:`Relocalizer.verify`): the obstacle end points of
   the episode's recent range profiles, mapped by ``T``, must land on obstacles the stored model
   saw (inliers) and not inside space it saw free (conflicts), and the stored obstacles must not
   lie inside the free space the agent sees now; a few rounds of ICP on the way refine ``T``;
3. **accepts** the best verified hypothesis (or, with geometry off, the paper's first match,
   optionally confirmed by ``confirm_matches`` agreeing matches);
4. after acceptance, **checks landmarks** every step (a detection mapped where the stored model
   knows objects should find one of its class), **refines** ``T`` from landmark pairs, and
   **undoes** a relocation the landmarks refute; and keeps looking for **bridges**: verified
   matches into *other* stored models, so that separate models of one house can be joined.

Every decision is counted (``decisions``), so ``episodes.jsonl`` can say why a relocation was
accepted, refused or undone.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, replace

import cv2
import numpy as np

from kgnav.agent import scan_search
from kgnav.common import se2
from kgnav.common.edt import distance_to_zero
from kgnav.memory.constants import JOIN_EPISODE
from kgnav.memory.evidence import MISS_RANGE, ScanTable
from kgnav.memory.geometry import OccupancyGrid, occupancy_from_scans
from kgnav.memory.posegraph import Anchor, Correction, DriftModel, correct, travelled
from kgnav.memory.relocator import Match

_START = "episode start"  # the anchor holding an episode corrected on itself in its frame
#: What the other side must lack near an object for it to be absent
#: (:attr:`RelocationConfig.absent_if`): any object, or one of the object's class.
ABSENT_IF = ("empty", "class")


@dataclass(frozen=True)
class RelocationConfig:
    """Tunable relocation behaviour. Distances in metres."""

    top_k: int = 3  # feature-space candidates considered per step
    # ... and of them, at most this many per stored model (each a stored state, so a
    # hypothesis of its own): with one, the model's nearest state, if it is a look-alike place,
    # hides the model's others from verification at every step
    per_model: int = 1
    geometry: bool = True  # verify hypotheses against range profiles (False: feature match only)
    confirm_matches: int = 2  # agreeing verified matches needed to accept (the paper: 1)
    confirm_window: int = 10  # steps within which they must fall
    confirm_tolerance: tuple[float, float] = (0.5, 15.0)  # m, degrees between transforms
    recent_scans: int = 40  # the episode's latest range profiles used to verify
    min_points: int = 80  # obstacle points the stored model must know to judge a hypothesis
    min_spread: float = 0.4  # m: the points must not all lie along one wall (least std dev)
    min_inliers: float = 0.75  # share of known points landing on a stored obstacle
    max_conflicts: float = 0.08  # share landing deep inside stored free space (or vice versa)
    inlier_distance: float = 0.2
    icp_rounds: int = 20  # alignment iterations at most; it stops when T no longer moves
    rejudge_after: int = 3  # steps before a refused hypothesis is judged again
    verify_per_step: int = 1  # hypotheses verified per step at most (the best matches first)
    # every this many steps while not relocated, search the stored models the views looked
    # most like for where the recent range profiles fit (kgnav.agent.scan_search), as well as
    # proposing from feature matches: a place the memory saw from afar, or whose nearest
    # looking states are look-alikes, is found by its walls (0: off, as in the paper;
    # docs/memory.md, "The scan search")
    scan_search: int = 10
    search_models: int = 2  # models searched each time (the most looked like)
    search_scans: int = 20  # recent profiles needed before searching
    search_refine: int = 3  # best distinct placements aligned and judged per model searched
    # at the episode's end, the late match also judges this many best distinct placements of
    # the whole episode's profiles in each of the search_models models (0: off)
    late_search: int = 2
    # a scan search's hypothesis (live, or the late search's) is accepted only when at least
    # this many of the episode's objects (seen twice) find their class there: positive
    # evidence, where walls alone fit a look-alike room of another house (0: no objects
    # needed, only none contradicting)
    search_support: int = 0
    # ... and only when the walls fit it at least this well (share of inliers; the live
    # verification's, and the whole episode's for the late search's): rooms of one shape in
    # other houses fit MiniWorld's calib episodes at 0.77-0.92, the right rooms at 0.85-1.00
    # (33 of 35 at 0.95 or more), and kgnav's train houses' at 0.96-1.00 under locobot noise
    search_inliers: float = 0.95
    # what the episode sees against what the memory saw from the same place: a placement's
    # appearance (Relocalizer.appearance) is the median, over the recent views that stored
    # states stood near (within look_radius m and look_heading degrees once placed), of the
    # cosine distance to the best-looking of those states ...
    look_radius: float = 1.0
    look_heading: float = 30.0
    # ... and a scan search's hypothesis (live, or the late search's) is accepted only when
    # at least look_views views have stored states near and their appearance is within
    # search_look times the relocation threshold: walls place a look-alike room of another
    # house as well as the right one, its walls and floors do not look the same (0: off)
    search_look: float = 0.0
    look_views: int = 3
    max_correction: tuple[float, float] = (1.0, 20.0)  # ICP may move T this much (m, degrees)
    landmark_radius: float = 1.5  # landmark pairing radius for checks and refinement (0: off)
    refine_pairs: int = 60  # most recent landmark pairs used to refine
    verify_checks: int = 15  # landmark checks before a relocation may be undone (0: never)
    verify_support: float = 0.25  # undo it when fewer checks than this share find their class
    merge_support: float = 0.5  # at the episode's end, merge into the matched model only above
    bridge_interval: int = 5  # after relocating, look for other models every this many steps
    reverify_interval: int = 10  # after relocating, re-verify (and refine) this often (0: off)
    unique: bool = True  # accept only an alignment no alternative start fits about as well
    unique_margin: float = 0.05  # an alternative within this inlier share makes it ambiguous
    merge_check: bool = True  # before merging, verify the whole episode's scans (and bridges')
    merge_scans: int = 200  # at most this many of the episode's profiles, evenly spread
    late_match: bool = True  # at the end, look for the models the whole episode fits (a merge
    # for an episode that never relocated, bridges for one that did)
    late_hypotheses: int = 2  # transforms judged per model (the most voted by feature matches)
    late_bend: bool = False  # with a drift model, a late match that no single transform lays
    # on the model gets the relocated merge's second chance: bent by its loop closures
    merge_objects: int = 3  # before merging, the episode's objects (seen twice) mapped near
    # stored ones must mostly find their class there, once at least this many can be checked
    # ... and with fewer to check, the walls alone must fit the whole episode this well: rooms
    # of one shape in different houses fit at 0.77-0.83 with no object to tell them apart,
    # the same room at 0.98-1.00 (MiniWorld train; the midpoint, rounded down)
    bare_inliers: float = 0.9
    # evidence of absence before merging: an object seen twice by one side (the episode or the
    # stored model) where the other side looked at it from at least this many states (within
    # MISS_RANGE, in view, unoccluded) and has nothing of its class (absent_if) within
    # landmark_radius counts against the alignment (0: off) ...
    absence_views: int = 3
    # ... and the merge is refused when at least this many objects are absent so and they
    # outnumber the episode's objects that found their class (a room of the same shape in
    # another house: its furniture stands elsewhere, where the memory saw the floor empty)
    absent_objects: int = 2
    # what "nothing" is: "class", none of the object's class, so a segmenter's confusion (a
    # bookshelf one side calls a lamp) counts too; "empty", no object of any class (the other
    # side saw the floor there). "empty" spared right relocations undone by confusions on
    # kgnav's train houses (2 of 120 episodes, no success changed) but let 5 wrong merges and
    # 2 wrong bridges through on MiniWorld's calib houses (none with "class"): in small rooms
    # another house's furniture often stands near something of another class
    absent_if: str = "class"
    # the odometry's drift (kgnav.memory.posegraph.DriftModel): before merging, stretches of the
    # episode verified on their own become loop closures that bend its poses onto the model
    # (None: odometry trusted as exact, one rigid transform, as without noise)
    drift: DriftModel | None = None
    closure_window: int = 20  # profiles per loop-closure stretch
    # a stretch whose aligned walls pin it less than this in its weakest direction (the ratio
    # of the smaller to the larger eigenvalue of the alignment's translational information)
    # is no loop closure: along one wall an alignment slides (0: no check)
    closure_constraint: float = 0.0
    # with a drift model, an episode stored as a new model is first corrected against itself:
    # a stretch that comes back to space the episode mapped at least this many profiles
    # earlier is a loop closure on that earlier map (0: off)
    self_closure_gap: int = 0
    # how precisely such a closure places the stretch (m, degrees): looser than a closure on a
    # stored model, since the earlier map is drawn with the same odometry and the aligner's
    # noise would otherwise outweigh an odometry that is good over short stretches
    self_closure_sigma: tuple[float, float] = (0.2, 8.0)
    # a kept closure is recorded as a link to the stored state nearest where it placed the
    # episode, when one lies this close (m); merges then optimise the whole model's pose
    # graph (kgnav.memory.posegraph.straighten) with every recorded episode's odometry
    link_radius: float = 1.5
    # a join's links are used only if they spread over at least this (m): links in one spot
    # pin the folded model's turn worse than the rigid fit of the whole model does
    join_link_span: float = 3.0
    joint: bool = True  # re-optimise the stored model at each merge (with a drift model)

    def __post_init__(self):
        if int(self.per_model) < 1:
            raise ValueError(f"per_model must be at least 1, got {self.per_model!r}")
        if self.absent_if not in ABSENT_IF:
            raise ValueError(f"absent_if must be one of {ABSENT_IF}, got {self.absent_if!r}")


@dataclass
class Relocation:
    """A match accepted in this episode (at most one stands at a time, as in the paper)."""

    step: int
    model_id: str
    state_id: str
    distance: float
    transform: tuple[float, float, float]  # episode frame -> model frame
    at: tuple[float, float] | None = None  # agent position at the match, episode frame
    checked: int = 0  # detections mapped where the stored model knows some object
    supported: int = 0  # ... of which found a remembered object of their own class
    inliers: float | None = None  # geometric verification: share of points on stored obstacles
    conflicts: float | None = None
    points: int = 0  # points the verification judged
    late: bool = False  # found at the episode's end from all its states, not while navigating
    source: str = "features"  # what proposed it: "features" or "scan search" (no state, no
    # distance: ``state_id`` is "" and ``distance`` NaN, as for a late match)
    # its appearance when accepted (Relocalizer.appearance): the median cosine distance of
    # the recent views to stored states near where it places them, and how many views had one
    look: float | None = None
    look_views: int = 0
    # the transform as accepted at ``step``: ``transform`` is refined as the episode goes on
    # (and, with drift, follows the odometry away from ``at``), so only this one says how
    # precisely the relocation placed the agent where it was made
    made: tuple[float, float, float] | None = None

    def __post_init__(self):
        if self.made is None:
            self.made = tuple(self.transform)


@dataclass
class Verdict:
    """The outcome of verifying one hypothesis."""

    ok: bool
    reason: str  # "verified", "few points", "geometry", "conflict"
    transform: tuple[float, float, float]
    inliers: float = 0.0
    conflicts: float = 0.0
    points: int = 0


class StoredGeometry:
    """A stored model's occupancy (:func:`~kgnav.memory.geometry.occupancy`) prepared for verifying
    hypotheses: the distance from every cell to the nearest stored obstacle, and its gradient
    (for aligning scans to it)."""

    def __init__(self, grid: OccupancyGrid):
        self.grid = grid
        obst = self.obstacle = grid.obstacle
        self.known = (grid.free > 0) | obst
        if obst.any():
            dist = distance_to_zero(~obst)
            self.dist = dist * grid.resolution
            # d(distance)/dx and /dy in metres per metre (columns are x, rows y)
            self.grad_y, self.grad_x = np.gradient(dist.astype(np.float32))
            # sampling is most of an alignment's time: one gather of three values per corner,
            # by flat row index (twice as fast as three 2-d fancy indexes)
            self._field = np.stack([self.dist, self.grad_x, self.grad_y], axis=-1).reshape(-1, 3)
        else:
            self.dist = np.full(obst.shape, np.inf, np.float32)
            self.grad_x = self.grad_y = None

    def sample(self, pts: np.ndarray):
        """Bilinear distance (m) and its gradient at points; ``inf`` outside the grid."""
        g = self.grid
        fx = (pts[:, 0] - g.x0) / g.resolution - 0.5
        fy = (pts[:, 1] - g.y0) / g.resolution - 0.5
        h, w = self.dist.shape
        ok = (fx >= 0) & (fx < w - 1) & (fy >= 0) & (fy < h - 1)
        d = np.full(len(pts), np.inf)
        gx = np.zeros(len(pts))
        gy = np.zeros(len(pts))
        if ok.any() and self.grad_x is not None:
            x, y = fx[ok], fy[ok]
            j, i = x.astype(int), y.astype(int)
            a, b = x - j, y - i
            w00, w01, w10, w11 = (1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b
            f, k = self._field, i * w + j
            v = (w00[:, None] * f.take(k, 0) + w01[:, None] * f.take(k + 1, 0)
                 + w10[:, None] * f.take(k + w, 0) + w11[:, None] * f.take(k + w + 1, 0))
            d[ok], gx[ok], gy[ok] = v[:, 0], v[:, 1], v[:, 2]
        return d, gx, gy

    def cells(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        g = self.grid
        j = np.floor((pts[:, 0] - g.x0) / g.resolution).astype(np.int64)
        i = np.floor((pts[:, 1] - g.y0) / g.resolution).astype(np.int64)
        h, w = self.known.shape
        inside = (i >= 0) & (i < h) & (j >= 0) & (j < w)
        return i, j, inside

    @classmethod
    def of(cls, model) -> StoredGeometry | None:
        scan = model.scan
        if scan is None:
            return None
        poses, ranges = [], []
        for s in model.states():
            d = model.graph.nodes[s]
            if "ranges" in d:
                poses.append((d["x"], d["y"], d["theta"]))
                ranges.append(d["ranges"])
        if not poses:
            return None
        # near: what the model searched for objects, as far as its evidence counts misses
        return cls(occupancy_from_scans(scan, poses, ranges, near_range=MISS_RANGE))


class Relocalizer:
    """Proposes, verifies, accepts, checks, refines and undoes relocations into a
    :class:`~kgnav.agent.memory.Memory` (see the module docstring)."""

    def __init__(self, memory, config: RelocationConfig | None = None):
        self.memory = memory
        self.config = config or RelocationConfig()
        self.reset()

    def reset(self) -> None:
        self.relocation: Relocation | None = None
        self.undone: list[Relocation] = []
        self.bridges: dict[str, Verdict] = {}  # other models verified during the episode
        self.decisions: Counter = Counter()
        # every hypothesis judged in the loop, for scoring against ground truth (never read
        # by the agent): [step, model id, transform as verified, agent's (x, y) then, source,
        # outcome (HYPOTHESIS_OUTCOMES)]
        self.hypotheses: list[list] = []
        self.matched: set[str] = set()  # models whose states the episode's views matched
        self._recent: deque = deque(maxlen=self.config.recent_scans)
        self._all: list = []  # every profile of the episode, for the check before merging
        self._steps: list[int] = []  # ... and the step of each
        self.correction: Correction | None = None  # the episode bent onto the merged model
        self._candidates: list[tuple[int, str, tuple]] = []
        self._failed: list[tuple[int, str, tuple]] = []  # recently refused hypotheses
        self._pairs: list[tuple] = []
        self.final: dict[str, Verdict] = {}  # the whole-episode verdicts, once asked
        self.late: Relocation | None = None  # the match found at the episode's end
        self._landmarks = (np.zeros((0, 2)), np.zeros(0, dtype=object))
        self._last_bridge = 0
        self._scan_tables: dict[str, ScanTable] = {}  # per stored model, for object_absence
        self._episode_table: tuple | None = None  # (episode model, its table)
        self._votes: Counter = Counter()  # steps each model held the view's nearest state
        self._pending: list[tuple] = []  # (step, Match, T) found by the scan search
        self._last_search = 0
        self._search_refuted: set[str] = set()  # models a scan search relocation was undone in
        self._geometry_memo: dict[tuple, tuple] = {}  # see _episode_geometry
        self._views: list = []  # (pose, unit features) of every state seen, for appearance

    # ------------------------------------------------------------------ proposing
    def observe(self, step: int, state, scan, episode=None) -> Relocation | None:
        """Note the state's range profile; while not relocated, try to relocate on it.
        Returns the relocation accepted at this step, if any. ``episode``: the episode's
        model so far, whose objects a scan search's hypothesis must not contradict."""
        if state.ranges is not None and scan is not None:
            self._recent.append((state.pose, np.asarray(state.ranges, np.float32), scan))
            self._all.append(self._recent[-1])
            self._steps.append(int(step))
        f = np.asarray(state.features, np.float32)
        self._views.append((tuple(state.pose), f / max(float(np.linalg.norm(f)), 1e-12)))
        if self.relocation is not None:
            if (self.config.bridge_interval > 0
                    and step - self._last_bridge >= self.config.bridge_interval):
                self._last_bridge = step
                self._bridge(state)
            return None
        best = None
        judged = 0
        per = self.config.per_model  # at least 1 (RelocationConfig checks)
        nearest = self.memory.nearest(state.features, self.config.top_k * per)
        matches = self._within(nearest, per)
        self.matched.update(m.model_id for m in matches)
        if nearest:  # the model the view looks most like, within the threshold or not
            self._votes[nearest[0].model_id] += 1
        self._search(step)
        self._pending = [p for p in self._pending if step - p[0] < self.config.confirm_window]
        hypotheses = [(p[1], p[2], "scan search") for p in self._pending]
        for m in matches:
            stored = self.memory.model(m.model_id)
            hypotheses.append((m, se2.anchor_transform(stored.pose(m.state_id), state.pose),
                               "features"))
        for m, T, source in hypotheses:
            if any(u.model_id == m.model_id and self._agree(u.transform, T) for u in self.undone):
                self.decisions["refuted before"] += 1
                self._drop_pending(m.model_id, T)
                continue
            if self.config.geometry:
                if self._judged_lately(step, m.model_id, T):
                    continue
                if judged >= self.config.verify_per_step:
                    break  # the rest wait for a later step: each judgement costs milliseconds
                judged += 1
                v = self.verify(m.model_id, T)
                self.decisions[v.reason] += 1
                judged_here = [int(step), m.model_id, v.transform,
                               (float(state.pose[0]), float(state.pose[1])), source, v.reason]
                self.hypotheses.append(judged_here)
                if not v.ok:
                    self._failed.append((step, m.model_id, tuple(T)))
                    self._drop_pending(m.model_id, T)
                    continue
            else:
                v = Verdict(True, "feature match", tuple(T))
                judged_here = None
            if not self._confirmed(step, m.model_id, v.transform):
                self.decisions["awaiting confirmation"] += 1
                _outcome(judged_here, "awaiting confirmation")
                continue
            if self.config.geometry and self.config.unique:
                alt = self.ambiguity(m.model_id, v)
                if alt is not None:  # a corridor, a symmetric room, a repeated room
                    self._refuse(step, m.model_id, T, "ambiguous")
                    _outcome(judged_here, "ambiguous")
                    continue
            if source == "scan search":
                refusal = self._search_refusal(episode, m.model_id, v)
                if refusal is not None:
                    self._refuse(step, m.model_id, T, refusal)
                    _outcome(judged_here, "refused by the episode")
                    continue
            if best is None or v.inliers > best[1].inliers:
                best = (m, v, source, judged_here)
            if not self.config.geometry:
                break  # the paper: the first match
        if best is None:
            return None
        m, v, source, judged_here = best
        _outcome(judged_here, "accepted")
        if source == "scan search":
            self.decisions["scan search accepted"] += 1
        look, looked = self.appearance(m.model_id, v.transform)
        self.relocation = Relocation(step, m.model_id, m.state_id, m.distance,
                                     tuple(float(x) for x in v.transform),
                                     (float(state.pose[0]), float(state.pose[1])),
                                     inliers=round(v.inliers, 3) if self.config.geometry else None,
                                     conflicts=round(v.conflicts, 3) if self.config.geometry
                                     else None, points=v.points, source=source,
                                     look=look, look_views=looked)
        self._last_bridge = step
        stored = self.memory.model(m.model_id)
        nodes = stored.graph.nodes
        objs = list(stored.objects())
        self._landmarks = (np.array([(nodes[o]["x"], nodes[o]["y"]) for o in objs],
                                    float).reshape(-1, 2),
                           np.array([nodes[o]["cls"] for o in objs], dtype=object))
        return self.relocation

    def take_model(self, model) -> None:
        """Judge a stored ``model`` as if it were this episode: its states' range profiles,
        in the order they were added, become the episode's (for :meth:`mergeable` with
        ``model`` as the episode: whether a whole stored model fits another; see
        :mod:`kgnav.agent.consolidation`)."""
        scan, nodes = model.scan, model.graph.nodes
        if scan is None:
            return
        for i, s in enumerate(model.states()):
            d = nodes[s]
            if d.get("ranges") is not None:
                self._all.append(((d["x"], d["y"], d["theta"]),
                                  np.asarray(d["ranges"], np.float32), scan))
                self._steps.append(i)

    def _judged_lately(self, step: int, model_id: str, T) -> bool:
        """A hypothesis agreeing with one that failed verification in the last few steps is
        not judged again yet (the scans have hardly changed)."""
        self._failed = [f for f in self._failed if step - f[0] < self.config.rejudge_after]
        return any(f[1] == model_id and self._agree(f[2], T) for f in self._failed)

    def _matches(self, features, k: int | None = None, per_model: int = 1):
        """The nearest stored states within the threshold (of the ``k`` nearest), at most
        ``per_model`` per model, nearest first."""
        return self._within(self.memory.nearest(features, k or self.config.top_k), per_model)

    def _within(self, nearest, per_model: int = 1):
        """Of the stored states ``nearest`` (nearest first), those within the threshold, at
        most ``per_model`` per model."""
        threshold = self.memory.threshold
        out, models = [], Counter()
        for m in nearest:
            if m.distance < threshold and models[m.model_id] < per_model:
                out.append(m)
                models[m.model_id] += 1
        return out

    def _search(self, step: int) -> None:
        """Every ``scan_search`` steps, search the ``search_models`` stored models the
        episode's views looked most like (:mod:`kgnav.agent.scan_search`) for where the recent
        range profiles fit. The ``search_refine`` best distinct placements are aligned (ICP)
        and judged; the best verified one becomes a pending hypothesis, verified like a
        feature match in the next steps, unless another fits about as well (as in
        :meth:`ambiguity`, but anywhere in the model: a repeated or symmetric room)."""
        c = self.config
        if (c.scan_search <= 0 or not c.geometry or step - self._last_search < c.scan_search
                or len(self._recent) < c.search_scans):
            return
        self._last_search = step
        ends, fans = self._episode_geometry(self._recent)
        if len(ends) < c.min_points:
            return
        votes = Counter({mid: n for mid, n in self._votes.items()
                         if mid not in self._search_refuted})
        for model_id, _ in votes.most_common(c.search_models):
            geo = self.memory.geometry(model_id)
            if geo is None or geo.grad_x is None:
                continue
            self.decisions["scan search"] += 1
            found = scan_search.distinct(scan_search.search(geo, ends))[:c.search_refine]
            judged = [self._judge(geo, ends, fans, self._align(geo, ends, q.transform))
                      for q in found]
            ok = [v for v in judged if v.ok]
            if not ok:
                self.decisions["scan search refused"] += 1
                continue
            best = max(ok, key=_margin)
            if any(w is not best and not self._agree(w.transform, best.transform)
                   and w.points >= c.min_points and w.inliers >= best.inliers - c.unique_margin
                   and w.conflicts <= c.max_conflicts for w in judged):
                self.decisions["scan search ambiguous"] += 1
                continue
            T = best.transform
            if not any(p[1].model_id == model_id and self._agree(p[2], T)
                       for p in self._pending):
                self._pending.append((step, Match(model_id, "", math.nan), T))

    def _refuse(self, step: int, model_id: str, T, decision: str) -> None:
        """Count a verified hypothesis refused as ``decision``; not judged again for a
        few steps."""
        self.decisions[decision] += 1
        self._failed.append((step, model_id, tuple(T)))
        self._drop_pending(model_id, T)

    def _search_refusal(self, episode, model_id: str, v: Verdict) -> str | None:
        """Why a scan search's verified hypothesis ``v`` is refused, or None: walls alone
        fit a look-alike room of another house as well as the right one, so its furniture
        must not stand elsewhere (the checks that undo a relocation, made before accepting
        it: no stored state vouches for this place), the walls must fit as a room fits
        itself, and (``search_look``) what stands between them must look the same."""
        c = self.config
        if episode is not None and self._objects_refute(episode, model_id, v.transform):
            return "scan search refuted by objects"
        if v.inliers < c.search_inliers:
            return "scan search walls only"
        if c.search_look > 0 and not self._looks_alike(model_id, v.transform):
            return "scan search unlike"
        return None

    def appearance(self, model_id: str, T, views=None) -> tuple[float | None, int]:
        """How the ``views`` (default: the ``recent_scans`` latest; ``(pose, unit
        features)``), placed in ``model_id`` by ``T``, look against the stored states near
        them (within ``look_radius`` and ``look_heading``): the median over the views that
        have any of the cosine distance to the best-looking one (None when none has), and
        how many views had one. The right place looks like what the memory saw there; a room
        of the same shape elsewhere, its walls and floor of other textures, does not."""
        c = self.config
        views = self._views[-c.recent_scans:] if views is None else views
        poses, feats = self.memory.looks(model_id)
        if not views or not len(poses):
            return None, 0
        P = np.array([v[0] for v in views], float)
        V = np.stack([v[1] for v in views])
        cos, sin = math.cos(T[2]), math.sin(T[2])
        qx = T[0] + cos * P[:, 0] - sin * P[:, 1]
        qy = T[1] + sin * P[:, 0] + cos * P[:, 1]
        near = np.hypot(qx[:, None] - poses[None, :, 0],
                        qy[:, None] - poses[None, :, 1]) <= c.look_radius
        turn = (P[:, 2:3] + T[2] - poses[None, :, 2] + math.pi) % (2 * math.pi) - math.pi
        near &= np.abs(turn) <= math.radians(c.look_heading)
        have = near.any(axis=1)
        if not have.any():
            return None, 0
        sims = np.where(near[have], V[have] @ feats.T, -np.inf).max(axis=1)
        return round(float(np.median(1.0 - sims)), 4), int(have.sum())

    def _spread_views(self, most: int = 200) -> list:
        """At most ``most`` of the episode's views, evenly spread: the whole episode's."""
        return self._views[::max(1, -(-len(self._views) // most))]

    def _looks_alike(self, model_id: str, T, views=None) -> bool:
        """Whether ``T`` into ``model_id`` passes the ``search_look`` check."""
        c = self.config
        look, looked = self.appearance(model_id, T, views)
        return (look is not None and looked >= c.look_views
                and look <= c.search_look * self.memory.threshold)

    def _objects_refute(self, episode, model_id: str, T) -> bool:
        """Whether the ``episode``'s objects refute ``T`` into ``model_id``: enough of them
        checked (``merge_objects``) and too few finding their class there (``merge_support``),
        or evidence of absence (:meth:`_absent`), or fewer than ``search_support`` finding
        their class there."""
        c = self.config
        if c.landmark_radius <= 0:
            return False
        checked, supported = self.object_support(episode, model_id, T)
        if supported < c.search_support:
            return True
        if checked >= c.merge_objects and supported < c.merge_support * checked:
            return True
        return c.absence_views > 0 and self._absent(episode, model_id, T, supported)

    def _drop_pending(self, model_id: str, T) -> None:
        self._pending = [p for p in self._pending
                         if not (p[1].model_id == model_id and self._agree(p[2], T))]

    def _confirmed(self, step: int, model_id: str, T) -> bool:
        need = self.config.confirm_matches
        if need <= 1:
            return True
        window = self.config.confirm_window
        self._candidates = [c for c in self._candidates if step - c[0] < window]
        agree = [c for c in self._candidates if c[1] == model_id and self._agree(c[2], T)]
        self._candidates.append((step, model_id, tuple(T)))
        return len(agree) + 1 >= need

    def _agree(self, a, b) -> bool:
        tol_xy, tol_th = self.config.confirm_tolerance
        return (math.dist(a[:2], b[:2]) <= tol_xy
                and se2.angle_diff(a[2], b[2]) <= math.radians(tol_th))

    # ------------------------------------------------------------------ verifying
    def verify(self, model_id: str, T, scans=None) -> Verdict:
        """Judge the hypothesis "the episode frame maps into ``model_id``'s by ``T``" against
        geometry (see the module docstring); ICP refines ``T`` on the way. ``scans``: the
        (pose, profile, geometry) triples to judge with (default: the latest
        ``recent_scans``)."""
        c = self.config
        geo = self.memory.geometry(model_id)
        scans = self._recent if scans is None else scans
        if geo is None or not scans:
            return Verdict(False, "few points", tuple(T))
        ends, fans = self._episode_geometry(scans)
        if len(ends) == 0:
            return Verdict(False, "few points", tuple(T))
        T0 = T = tuple(float(v) for v in T)
        if geo.grad_x is not None:
            T = self._align(geo, ends, T0)
        v0 = self._judge(geo, ends, fans, T0)
        if (T == T0 or math.dist(T[:2], T0[:2]) > c.max_correction[0]
                or se2.angle_diff(T[2], T0[2]) > math.radians(c.max_correction[1])):
            return v0  # no refinement, or ICP wandered off: judge the hypothesis as proposed
        v1 = self._judge(geo, ends, fans, T)
        return max((v0, v1), key=lambda v: (v.ok, v.inliers - v.conflicts))

    def _align(self, geo: StoredGeometry, ends: np.ndarray, T):
        """Scan-to-map alignment: Gauss-Newton on the distance from the mapped obstacle points
        to the stored obstacles (bilinear distance field, as Hector SLAM), points with a
        stored partner within a shrinking radius only; at most ``icp_rounds`` iterations."""
        c = self.config
        tx, ty, th = T
        for k in range(c.icp_rounds):
            pts = se2.apply_to_points((tx, ty, th), ends)
            d, gx, gy = geo.sample(pts)
            i, j, inside = geo.cells(pts)
            known = np.zeros(len(pts), bool)
            known[inside] = geo.known[i[inside], j[inside]]
            use = known & (d <= max(0.8 * (1 - k / max(c.icp_rounds - 1, 1)), 0.3))
            if use.sum() < c.min_points // 2:
                break
            px, py = pts[use, 0] - tx, pts[use, 1] - ty
            J = np.stack([gx[use], gy[use], -gx[use] * py + gy[use] * px], axis=1)
            r = d[use]
            H = J.T @ J + np.diag([1e-3, 1e-3, 1e-2])  # damped: a wall alone fixes 2 of 3 dof
            delta = np.linalg.solve(H, -J.T @ r)
            tx, ty, th = tx + delta[0], ty + delta[1], th + delta[2]
            if abs(delta[0]) + abs(delta[1]) < 1e-3 and abs(delta[2]) < 1e-4:
                break
        return float(tx), float(ty), float(se2.wrap_angle(th))

    def ambiguity(self, model_id: str, v: Verdict, scans=None) -> Verdict | None:
        """An alignment elsewhere that fits the scans about as well as the verified ``v``
        (inliers within ``unique_margin``, conflicts allowed), or None when ``v`` is unique.

        Alignment is started from alternatives around ``v``'s transform: shifted 0.75 and
        1.5 m in eight directions, and turned by a quarter, half and three quarters of a turn
        about the scans' centre. A corridor (shifted along it), a symmetric room (turned) or a
        repeated room next door lets one of them converge elsewhere and fit as well: the scans
        then do not tell where the agent is, and the match must wait for more of them.
        """
        c = self.config
        geo = self.memory.geometry(model_id)
        scans = self._recent if scans is None else scans
        if geo is None or geo.grad_x is None or not scans:
            return None
        ends, fans = self._episode_geometry(scans)
        T = v.transform
        centre = se2.apply_to_points(T, ends).mean(axis=0)
        for alt in _alternatives(T, centre):
            T1 = self._align(geo, ends, alt)
            if self._agree(T1, T):
                continue  # back to the verified alignment
            w = self._judge(geo, ends, fans, T1)
            if (w.points >= c.min_points and w.inliers >= v.inliers - c.unique_margin
                    and w.conflicts <= c.max_conflicts):
                return w
        return None

    def _merge_scans(self, scans=None) -> list:
        """At most ``merge_scans`` of ``scans`` (default: the episode's), evenly spread."""
        c = self.config
        scans = self._all if scans is None else scans
        if len(scans) > c.merge_scans:
            scans = [scans[i] for i in np.linspace(0, len(scans) - 1, c.merge_scans).astype(int)]
        return scans

    def _episode_verdict(self, model_id: str, T, scans, episode=None) -> Verdict:
        """``T`` judged against the whole episode's profiles ``scans``, ambiguity included,
        and (with the ``episode``'s model) against the objects: a room of the same shape in
        another house rarely holds the same furniture in the same places."""
        c = self.config
        v = self.verify(model_id, T, scans)
        if v.ok and c.unique and self.ambiguity(model_id, v, scans) is not None:
            v = Verdict(False, "ambiguous", v.transform, v.inliers, v.conflicts, v.points)
        return self._object_verdict(model_id, episode, v)

    def _object_verdict(self, model_id: str, episode, v: Verdict) -> Verdict:
        """``v`` refused as ``objects`` when the episode's objects mapped by ``v.transform``
        mostly find another class where the stored model has objects, as ``walls only`` when
        too few of them can be checked (fewer than ``merge_objects``) and the walls fit below
        ``bare_inliers``, or as ``objects absent`` when objects of either side stand where the
        other looked and saw none of their class (:meth:`object_absence`)."""
        c = self.config
        if not v.ok or episode is None or c.landmark_radius <= 0:
            return v
        checked, supported = self.object_support(episode, model_id, v.transform)
        if c.merge_objects > 0 and checked >= c.merge_objects and (
                supported < c.merge_support * checked):
            return Verdict(False, "objects", v.transform, v.inliers, v.conflicts, v.points)
        if checked < c.merge_objects and v.inliers < c.bare_inliers:
            return Verdict(False, "walls only", v.transform, v.inliers, v.conflicts, v.points)
        if c.absence_views > 0 and self._absent(episode, model_id, v.transform, supported):
            return Verdict(False, "objects absent", v.transform, v.inliers, v.conflicts,
                           v.points)
        return v

    def _absent(self, episode, model_id: str, T, supported: int | None = None) -> bool:
        """At least ``absent_objects`` objects absent (:meth:`object_absence`) under ``T``,
        and more of them than the episode's objects that find their class there."""
        absent = self.object_absence(episode, model_id, T)
        if absent < self.config.absent_objects:
            return False
        if supported is None:
            supported = self.object_support(episode, model_id, T)[1]
        return absent > supported

    def object_absence(self, episode, model_id: str, T) -> int:
        """How many objects seen at least twice, by the ``episode`` or by stored model
        ``model_id`` (the episode's mapped by ``T``), lie where the other side had them in view
        from at least ``absence_views`` states within :data:`MISS_RANGE` and knows no object
        of their class within ``landmark_radius`` (``absent_if="empty"``: none at all): evidence
        that ``T`` is wrong, strongest in look-alike rooms of another house, whose walls fit
        but whose furniture stands elsewhere. A phantom seen twice counts too, hence the
        comparison with the support in :meth:`_object_verdict`."""
        stored = self.memory.model(model_id)
        if stored is None or stored.scan is None or episode.scan is None:
            return 0
        if model_id not in self._scan_tables:
            self._scan_tables[model_id] = ScanTable(stored)
        T = tuple(float(v) for v in T)
        # a glimpse says little: only objects seen twice are evidence
        return (self._absent_from(episode, T, stored, self._scan_tables[model_id])
                + self._absent_from(stored, se2.inverse(T), episode, self._table_of(episode)))

    def _absent_from(self, model, T, other, table: ScanTable) -> int:
        """How many of ``model``'s objects seen at least twice, mapped by ``T`` into
        ``other``, lie where ``other`` had them in view (``table``) from at least
        ``absence_views`` states and knows no object of their class (``absent_if="empty"``:
        none at all) within ``landmark_radius``."""
        c = self.config
        if not len(table):
            return 0
        n = model.graph.nodes
        count = 0
        for o in model.objects():
            d = n[o]
            if d.get("n_views", 1) < 2:
                continue
            x, y = se2.apply_to_point(T, d["x"], d["y"])
            cls = d["cls"] if c.absent_if == "class" else None  # "empty": any class will do
            if other.nearest_object(cls, x, y, c.landmark_radius) is not None:
                continue
            if len(table.covering(x, y, MISS_RANGE)) >= c.absence_views:
                count += 1
        return count

    def _table_of(self, episode) -> ScanTable:
        """The growing ``episode`` model's :class:`ScanTable`, extended by the states it
        gained since the last call (rebuilding it at every re-verification cost half a
        millisecond a step)."""
        cached = self._episode_table
        if cached is None or cached[0] is not episode or cached[1].states_read > episode.n_states:
            self._episode_table = (episode, ScanTable(episode))
        else:
            cached[1].extend(episode)
        return self._episode_table[1]

    def object_support(self, episode, model_id: str, T) -> tuple[int, int]:
        """How many of the ``episode``'s objects seen at least twice land, mapped by ``T``,
        within ``landmark_radius`` of objects of the stored model (checked), and how many of
        those find one of their own class there (supported)."""
        stored = self.memory.model(model_id)
        sn = stored.graph.nodes
        objs = list(stored.objects())
        if not objs:
            return 0, 0
        xy = np.array([(sn[o]["x"], sn[o]["y"]) for o in objs], float)
        cls = np.array([sn[o]["cls"] for o in objs], dtype=object)
        checked = supported = 0
        en = episode.graph.nodes
        for o in episode.objects():
            d = en[o]
            if d["n_views"] < 2:
                continue  # a glimpse says little
            x, y = se2.apply_to_point(T, d["x"], d["y"])
            near = np.hypot(xy[:, 0] - x, xy[:, 1] - y) <= self.config.landmark_radius
            if near.any():
                checked += 1
                supported += bool((cls[near] == d["cls"]).any())
        return checked, supported

    def _episode_hypotheses(self, episode, refused: dict) -> dict[str, list]:
        """Frame transforms into stored models proposed by the feature matches of the
        episode's states (about a hundred of them, evenly spread): per model, the
        ``late_hypotheses`` most voted (agreeing transforms vote together), skipping those
        that agree with a transform already refused for that model."""
        ids, feats = episode.state_features()
        votes: dict[str, list] = {}
        for i in range(0, len(ids), max(1, len(ids) // 100)):
            pose = episode.pose(ids[i])
            for m in self._matches(feats[i]):
                T = se2.anchor_transform(self.memory.model(m.model_id).pose(m.state_id), pose)
                if any(self._agree(T, u) for u in refused.get(m.model_id, ())):
                    continue
                clusters = votes.setdefault(m.model_id, [])
                for cl in clusters:
                    if self._agree(cl[0], T):
                        cl[1] += 1
                        break
                else:
                    clusters.append([T, 1])
        k = self.config.late_hypotheses
        return {mid: [cl[0] for cl in sorted(cls, key=lambda cl: -cl[1])[:k]]
                for mid, cls in votes.items()}

    def _searched_hypotheses(self, scans, refused: dict) -> dict[str, list]:
        """With ``late_search``, the ``late_search`` best distinct placements of the whole
        episode's profiles ``scans`` in each of the ``search_models`` models its views looked
        most like (:mod:`kgnav.agent.scan_search`), less those agreeing with a transform
        already refused for that model: an episode that shared no stored state with a model
        may still have walked its rooms."""
        c = self.config
        if c.late_search <= 0 or not self._votes:
            return {}
        ends, _ = self._episode_geometry(scans)
        if len(ends) < c.min_points:
            return {}
        out: dict[str, list] = {}
        for mid, _ in self._votes.most_common(c.search_models):
            geo = self.memory.geometry(mid)
            if geo is None or geo.grad_x is None:
                continue
            self.decisions["late search"] += 1
            found = scan_search.distinct(scan_search.search(geo, ends))[:c.late_search]
            Ts = [q.transform for q in found
                  if not any(self._agree(q.transform, u) for u in refused.get(mid, ()))]
            if Ts:
                out[mid] = Ts
        return out

    def mergeable(self, episode=None) -> Relocation | None:
        """The relocation to merge the episode with at its end, or None to store it as a new
        model.

        One that stood but that landmarks supported only weakly, or (with ``merge_check``)
        that the whole episode's scans refute, would misplace a whole episode for good and is
        not merged. With ``merge_check``, bridges too must fit the whole episode, and with
        ``late_match`` and the ``episode``'s model, the feature matches of all its states
        propose more: the other stored models the whole episode verifiably fits become
        bridges, or, when no relocation stands, the best of them the model to merge into
        (``late``). A look at the whole episode finds what the few steps of a corridor or a
        doorway could not, and separate models of one house join. The verdicts are kept in
        :attr:`final` and counted in :attr:`decisions`."""
        c = self.config
        r = self.relocation
        self.correction = None
        if r is not None and self.refuted(r, c.merge_support):
            r = None
        if not (c.merge_check and c.geometry):
            return r
        scans = self._merge_scans()
        self.final = {}
        refused: dict[str, list] = {}
        if r is not None:
            v = self.final[r.model_id] = self._episode_verdict(r.model_id, r.transform, scans,
                                                               episode)
            if not v.ok and c.drift is not None and v.reason in ("geometry", "conflict"):
                v = self._bent_verdict(r.model_id, r.transform, v, episode)
            if v.ok:
                r.transform = v.transform  # aligned on the whole episode: the most precise
            else:
                self.decisions[f"merge refused: {v.reason}"] += 1
                refused[r.model_id] = [r.transform]
                r = None
                self.correction = None
        hyps: dict[str, list] = {mid: [b.transform] for mid, b in self.bridges.items()}
        searched: set[tuple] = set()  # (model, transform) proposed by the late scan search
        if episode is not None and c.late_match:
            for mid, Ts in self._episode_hypotheses(episode, refused).items():
                hyps.setdefault(mid, []).extend(Ts)
            for mid, Ts in self._searched_hypotheses(scans, refused).items():
                hyps.setdefault(mid, []).extend(Ts)
                searched.update((mid, tuple(T)) for T in Ts)
        found: dict[str, Verdict] = {}
        bent: dict[str, tuple[Verdict, Correction]] = {}  # late matches made by bending
        tried: set[str] = set()
        for mid, Ts in sorted(hyps.items()):
            if r is not None and mid == r.model_id:
                continue
            for T in Ts:
                v = self._episode_verdict(mid, T, scans, episode)
                if (not v.ok and r is None and c.late_bend and c.drift is not None
                        and v.reason in ("geometry", "conflict") and mid not in tried):
                    tried.add(mid)  # one bend per model: it costs a pose graph
                    v = self._bent_verdict(mid, T, v, episode)
                    if v.ok:
                        bent[mid], self.correction = (v, self.correction), None
                if v.ok and (mid, tuple(T)) in searched:
                    # proposed by the walls alone, as a live scan search's hypothesis is
                    if v.inliers < c.search_inliers:
                        v = replace(v, ok=False, reason="search walls only")
                    elif (c.search_support > 0 and self.object_support(episode, mid,
                                                                     v.transform)[1]
                            < c.search_support):
                        v = replace(v, ok=False, reason="search unsupported")
                    elif c.search_look > 0 and not self._looks_alike(
                            mid, v.transform, self._spread_views()):
                        v = replace(v, ok=False, reason="search unlike")
                if not v.ok:
                    self.decisions[f"episode match refused: {v.reason}"] += 1
                elif mid not in found or _margin(v) > _margin(found[mid]):
                    found[mid] = v
            if mid in found:
                self.final[mid] = found[mid]
        dropped = set(self.bridges) - set(found)
        self.decisions["bridge refuted by episode"] += len(dropped)
        if r is None and found and c.late_match:
            mid = max(sorted(found), key=lambda m: _margin(found[m]))
            v = found.pop(mid)
            look, looked = self.appearance(mid, v.transform, self._spread_views())
            r = self.late = Relocation(len(self._all), mid, "", math.nan, v.transform, (0.0, 0.0),
                                       inliers=round(v.inliers, 3),
                                       conflicts=round(v.conflicts, 3), points=v.points,
                                       late=True, look=look, look_views=looked)
            self.decisions["late match"] += 1
            # bent onto that model, the bend is the merge's (a rigid late match is bent below)
            if mid in bent and bent[mid][0] is v:
                self.correction = bent[mid][1]
        self.bridges = found if r is not None else {}
        if r is not None and c.drift is not None and self.correction is None:
            self.correction = self.close_loops(r.model_id, r.transform)
        return r

    def _bent_verdict(self, model_id: str, T, rigid: Verdict, episode=None) -> Verdict:
        """A drifting episode that no single transform lays on the model: judge it again with
        its poses bent by its loop closures (:meth:`close_loops`). Kept, the correction is
        :attr:`correction` and the verdict carries ``T`` (the bend already maps the chain)."""
        fix = self.close_loops(model_id, T)
        if fix is None:
            return rigid
        scans = self._merge_scans([(q, r, scan) for q, (_, r, scan)
                                   in zip(fix.poses, self._all, strict=True)])
        v = self.verify(model_id, (0.0, 0.0, 0.0), scans)
        if v.ok and self.config.unique and self.ambiguity(model_id, v, scans) is not None:
            v = Verdict(False, "ambiguous", v.transform, v.inliers, v.conflicts, v.points)
        if v.ok:  # the objects judged by the rigid T: landmark_radius spans the bend
            v = replace(v, ok=self._object_verdict(model_id, episode,
                                                   replace(v, transform=tuple(T))).ok)
        if not v.ok:
            return rigid
        self.decisions["merged after loop closures"] += 1
        fix.poses = [se2.compose(v.transform, q) for q in fix.poses]
        self.correction = fix
        return Verdict(True, "verified", tuple(T), v.inliers, v.conflicts, v.points)

    def close_loops(self, model_id: str, T) -> Correction | None:
        """The episode's pose chain laid on ``model_id`` (see :mod:`kgnav.memory.posegraph`):
        every ``closure_window`` profiles that verify against the stored geometry on their own
        are a loop closure, each aligned starting from the previous one's transform (the drift
        changes slowly); inconsistent closures are rejected and counted. None when no closure
        can be trusted: the episode then keeps the rigid ``T``."""
        c = self.config
        geo = self.memory.geometry(model_id)
        if geo is None or geo.grad_x is None or not self._all:
            return None
        chain = [tuple(float(v) for v in p) for p, _, _ in self._all]
        anchors = []
        Tk = tuple(T)
        w = max(int(c.closure_window), 1)
        for start in range(0, len(self._all), w):
            stretch = self._all[start:start + w]
            if len(stretch) < max(w // 2, 1) and anchors:
                break  # a short tail: its poses follow the chain
            Ta, ends, why = self._fit_stretch(geo, stretch, Tk)
            if Ta is None:
                if why:
                    self.decisions[f"loop closure refused: {why}"] += 1
                continue
            if _constraint(geo, ends, Ta, c.inlier_distance) < c.closure_constraint:
                # the stretch saw walls of mostly one direction: it can slide along them
                self.decisions["loop closure refused: degenerate"] += 1
                continue
            mid = start + len(stretch) // 2
            anchors.append(Anchor(mid, se2.compose(Ta, chain[mid]), f"step {self._steps[mid]}"))
            Tk = Ta
        if not anchors:
            return None
        fix = correct(chain, anchors, c.drift)
        if fix is None:
            self.decisions["loop closures inconsistent"] += 1
            return None
        self.decisions["loop closure kept"] += len(fix.kept)
        self.decisions["loop closure rejected"] += len(fix.rejected)
        return fix

    def _fit_stretch(self, geo: StoredGeometry, stretch, T):
        """``stretch`` (profiles) aligned on its own to ``geo`` starting from ``T``, as
        ``(Ta, ends, None)`` when it verifies there; ``(None, ends, why)`` when it does not
        (``why`` None when the stretch has no obstacle to judge)."""
        ends, fans = self._episode_geometry(stretch)
        if len(ends) == 0:
            return None, ends, None
        Ta = self._align(geo, ends, T)
        # how far the stretch itself moved (T's translation swings with any turn about the
        # episode's origin, far from here)
        c = self.config
        cx, cy = ends.mean(axis=0)
        if (math.dist(se2.apply_to_point(Ta, cx, cy), se2.apply_to_point(T, cx, cy))
                > c.max_correction[0]
                or se2.angle_diff(Ta[2], T[2]) > math.radians(c.max_correction[1])):
            return None, ends, "alignment wandered"
        v = self._judge(geo, ends, fans, Ta)
        return (Ta, ends, None) if v.ok else (None, ends, v.reason or "not verified")

    def close_own_loops(self) -> Correction | None:
        """The episode's pose chain corrected against itself, for an episode stored as a new
        model (the first in a house has nothing else to close loops on, and its drift would
        bend the memory for good): each ``closure_window`` stretch is aligned to the map of the
        profiles it follows by at least ``self_closure_gap`` (rebuilt every two stretches), and
        one that verifies on that map is a loop closure, as :meth:`close_loops` makes them on a
        stored model's; the start anchors the frame. Inconsistent closures are rejected. None
        without a closure the odometry does not already explain (the chain as it is); the
        correction is kept in :attr:`correction` (episode frame)."""
        c = self.config
        w = max(int(c.closure_window), 1)
        gap = int(c.self_closure_gap)
        n = len(self._all)
        self.correction = None
        if c.drift is None or gap <= 0 or n < gap + w:
            return None
        chain = [tuple(float(v) for v in p) for p, _, _ in self._all]
        anchors = [Anchor(0, chain[0], _START)]
        geo, cut = None, -1
        for start in range(gap, n, w):
            stretch = self._all[start:start + w]
            if len(stretch) < max(w // 2, 1):
                break
            want = ((start - gap) // (2 * w)) * 2 * w + w  # profiles of the earlier map
            if want != cut:
                cut = want
                early = self._all[:cut]
                grid = occupancy_from_scans(early[0][2], [p for p, _, _ in early],
                                            [r for _, r, _ in early], near_range=MISS_RANGE)
                geo = StoredGeometry(grid)
            if geo.grad_x is None:
                continue
            ends, fans = self._episode_geometry(stretch)
            if len(ends) == 0:
                continue
            # from the odometry itself (no transform): one closure gone astray does not
            # lead the next (on train this was truer than starting from the last closure)
            Ta = self._align(geo, ends, (0.0, 0.0, 0.0))
            cx, cy = ends.mean(axis=0)
            if (math.dist(se2.apply_to_point(Ta, cx, cy), (cx, cy)) > c.max_correction[0]
                    or abs(se2.wrap_angle(Ta[2])) > math.radians(c.max_correction[1])):
                self.decisions["own loop closure refused: alignment wandered"] += 1
                continue
            v = self._judge(geo, ends, fans, Ta)
            if not v.ok:
                continue  # most stretches see new space: not counted
            mid = start + len(stretch) // 2
            anchors.append(Anchor(mid, se2.compose(Ta, chain[mid]), f"step {self._steps[mid]}"))
        if len(anchors) < 2:
            return None
        sxy, sth = c.self_closure_sigma
        drift = replace(c.drift, anchor_xy=float(sxy), anchor_theta=math.radians(sth))
        fix = correct(chain, anchors, drift)
        if fix is None or len(fix.kept) < 2:
            self.decisions["own loop closures inconsistent"] += 1
            return None
        self.decisions["own loop closure kept"] += len(fix.kept) - 1
        self.decisions["own loop closure rejected"] += len(fix.rejected)
        self.correction = fix
        return fix

    def closure_states(self, episode) -> list[tuple[str, bool]]:
        """The ``episode`` model's states the :attr:`correction`'s loop closures placed, each
        with whether the optimisation kept it (empty without a correction)."""
        fix = self.correction
        if fix is None or not self._steps:
            return []
        ids = list(episode.states())
        steps = np.array([int(episode.graph.nodes[s].get("step", 0)) for s in ids])
        out = []
        for kept, anchors in ((True, fix.kept), (False, fix.rejected)):
            for a in anchors:
                if a.source == _START:
                    continue  # the frame's anchor, not a loop closure
                k = int(np.abs(steps - self._steps[a.node]).argmin())
                out.append((ids[k], kept))
        return out

    def odometry_records(self, episode) -> dict[str, list[float]]:
        """The raw odometry of each of the ``episode`` model's states, to record on it
        (:attr:`~kgnav.memory.model.AbstractModel.odometry`) before any correction moves them:
        its pose (the odometry's, episode frame) with the distance driven and angle turned up
        to the nearest profile by step. Empty without a drift model (exact odometry needs no
        pose graph)."""
        if self.config.drift is None or not self._steps:
            return {}
        driven, turned = travelled([p for p, _, _ in self._all])
        steps = np.asarray(self._steps)
        g = episode.graph
        out = {}
        for sid in episode.states():
            d = g.nodes[sid]
            k = int(np.abs(steps - int(d.get("step", 0))).argmin())
            out[f"{episode.model_id}/{sid}"] = [int(d.get("step", 0)), d["x"], d["y"],
                                                d["theta"], float(driven[k]), float(turned[k])]
        return out

    def closure_links(self, episode, model_id: str) -> dict[str, tuple[str, tuple]]:
        """For the kept loop closures of the :attr:`correction` on stored model ``model_id``:
        the ``episode`` state each placed (``"model_id/sN"``) -> (the stored state nearest to
        where the closure put it, within ``link_radius``; the state's pose relative to that
        stored state, as measured). Kept with the model, they tie the episode to the stored
        states again whenever the model's pose graph is optimised
        (:func:`kgnav.memory.posegraph.straighten`). Call before the episode is bent."""
        fix = self.correction
        if fix is None or not self._steps or model_id not in self.memory.models:
            return {}
        stored = self.memory.model(model_id)
        sg = stored.graph.nodes
        st_ids = list(stored.states())
        if not st_ids:
            return {}
        st_xy = np.array([(sg[s]["x"], sg[s]["y"]) for s in st_ids], float)
        ids = list(episode.states())
        steps = np.array([int(episode.graph.nodes[s].get("step", 0)) for s in ids])
        out = {}
        for a in fix.kept:
            if a.source == _START:
                continue
            k = int(np.abs(steps - self._steps[a.node]).argmin())
            d = episode.graph.nodes[ids[k]]
            odo = self._all[a.node][0]
            # where the closure puts the state: its anchor, then the odometry from there
            at = se2.compose(a.pose, se2.compose(se2.inverse(tuple(odo)),
                                                 (d["x"], d["y"], d["theta"])))
            near = np.hypot(st_xy[:, 0] - at[0], st_xy[:, 1] - at[1])
            j = int(near.argmin())
            if near[j] > self.config.link_radius:
                continue
            to = st_ids[j]
            rel = se2.compose(se2.inverse((sg[to]["x"], sg[to]["y"], sg[to]["theta"])), at)
            out[f"{episode.model_id}/{ids[k]}"] = (sg[to]["origin"].split()[0], rel)
        return out

    def model_links(self, model, model_id: str, T) -> list[dict]:
        """Links for a whole stored ``model`` (taken with :meth:`take_model`) that fits stored
        model ``model_id`` by ``T`` (a join, :mod:`kgnav.agent.consolidation`): its states,
        ``closure_window`` at a time in the order it stored them, each stretch aligned on its
        own to ``model_id``'s obstacles starting from ``T`` and kept only where it verifies;
        the middle state of each kept stretch linked to the nearest state of ``model_id``
        (within ``link_radius``) with its pose relative to it, as loop closures to record
        (episode :data:`JOIN_EPISODE`). Two models bent differently by their creators'
        drift fit one rigid ``T`` only on average; the links let the joined model's pose
        graph (:func:`kgnav.memory.posegraph.straighten`) lay each part where it fits."""
        c = self.config
        geo = self.memory.geometry(model_id)
        stored = self.memory.model(model_id)
        if geo is None or geo.grad_x is None or stored is None or not self._all:
            return []
        g, sg = model.graph.nodes, stored.graph.nodes
        ids = [s for s in model.states() if g[s].get("ranges") is not None]  # as take_model
        st_ids = list(stored.states())
        if len(ids) != len(self._all) or not st_ids:
            return []
        st_xy = np.array([(sg[s]["x"], sg[s]["y"]) for s in st_ids], float)
        T = tuple(float(v) for v in T)
        w = max(int(c.closure_window), 1)
        out, spots = [], []
        for start in range(0, len(self._all), w):
            stretch = self._all[start:start + w]
            if len(stretch) < max(w // 2, 1):
                continue
            Ta, _, why = self._fit_stretch(geo, stretch, T)
            if Ta is None:
                if why:
                    self.decisions["join link refused"] += 1
                continue
            d = g[ids[start + len(stretch) // 2]]
            at = se2.compose(Ta, (d["x"], d["y"], d["theta"]))
            near = np.hypot(st_xy[:, 0] - at[0], st_xy[:, 1] - at[1])
            j = int(near.argmin())
            if near[j] > c.link_radius:
                continue
            to = sg[st_ids[j]]
            rel = se2.compose(se2.inverse((to["x"], to["y"], to["theta"])), at)
            out.append({"state": d["origin"].split()[0], "episode": JOIN_EPISODE, "kept": True,
                        "to": to["origin"].split()[0], "rel": [float(v) for v in rel]})
            spots.append(at[:2])
        pts = np.asarray(spots, float).reshape(-1, 2)
        span = float(np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1)).max()
                     ) if len(pts) > 1 else 0.0
        if span < c.join_link_span:
            self.decisions["join links too close together"] += 1
            return []
        self.decisions["join link"] += len(out)
        return out

    def corrected_poses(self, episode, T) -> dict[str, tuple[float, float, float]]:
        """With a :attr:`correction`, each of the ``episode`` model's states' pose bent as its
        nearest chain node (by step) was, in the episode frame (so that ``T``, episode ->
        model, still maps the episode onto the model); empty without one."""
        fix = self.correction
        if fix is None or not self._steps:
            return {}
        steps = np.asarray(self._steps)
        Tinv = se2.inverse(tuple(T))
        # the move of each chain node, in the episode frame
        moves = [se2.compose(se2.compose(Tinv, q), se2.inverse(p))
                 for (p, _, _), q in zip(self._all, fix.poses, strict=True)]
        g = episode.graph
        out = {}
        for sid in episode.states():
            d = g.nodes[sid]
            k = int(np.abs(steps - int(d.get("step", 0))).argmin())
            out[sid] = se2.compose(moves[k], (d["x"], d["y"], d["theta"]))
        return out

    def _episode_geometry(self, scans):
        # the checks at an episode's end ask for the same scans' geometry a dozen times
        # (verification, ambiguity, each hypothesis): the last few answers are kept, for
        # the very same scan objects only
        key = tuple(map(id, scans))
        hit = self._geometry_memo.get(key)
        if hit is not None and all(a is b for a, b in zip(hit[0], scans, strict=True)):
            return hit[1], hit[2]
        ends, fans = [], []
        for pose, r, scan in scans:
            ends.append(scan.endpoints(pose, r))
            fans.append(scan.fan(pose, r, margin=0.35))
        ends = np.concatenate(ends) if ends else np.zeros((0, 2))
        ends.flags.writeable = False  # shared between callers
        if len(self._geometry_memo) >= 4:
            self._geometry_memo.pop(next(iter(self._geometry_memo)))
        self._geometry_memo[key] = (list(scans), ends, fans)
        return ends, fans

    def _judge(self, geo: StoredGeometry, ends, fans, T) -> Verdict:
        c = self.config
        pts = se2.apply_to_points(T, ends)
        i, j, inside = geo.cells(pts)
        known = np.zeros(len(pts), bool)
        known[inside] = geo.known[i[inside], j[inside]]
        n = int(known.sum())
        if n < c.min_points or _spread(pts[known]) < c.min_spread:
            return Verdict(False, "few points", tuple(T), points=n)
        d = geo.dist[i[known], j[known]]
        inliers = float((d <= c.inlier_distance).mean())
        # an obstacle seen now where the memory saw open floor, far from any stored obstacle
        deep_free = (geo.grid.free[i[known], j[known]] > 0) & (d > 0.5)
        conflicts = float(deep_free.mean())
        # stored obstacles inside the free space the agent sees now
        conflicts = max(conflicts, self._through_walls(geo, fans, T))
        ok = inliers >= c.min_inliers and conflicts <= c.max_conflicts
        reason = "verified" if ok else ("conflict" if conflicts > c.max_conflicts else "geometry")
        return Verdict(ok, reason, tuple(T), inliers, conflicts, n)

    @staticmethod
    def _through_walls(geo: StoredGeometry, fans, T) -> float:
        """Share of the currently seen free space (known to the stored model) where the
        stored model has an obstacle."""
        g = geo.grid
        polys = [np.floor((se2.apply_to_points(T, poly) - (g.x0, g.y0)) / g.resolution)
                 .astype(np.int32) for poly in fans]
        allp = np.concatenate(polys)
        h, w = g.free.shape
        i0, j0 = max(int(allp[:, 1].min()), 0), max(int(allp[:, 0].min()), 0)
        i1, j1 = min(int(allp[:, 1].max()) + 1, h), min(int(allp[:, 0].max()) + 1, w)
        if i0 >= i1 or j0 >= j1:
            return 0.0
        mask = np.zeros((i1 - i0, j1 - j0), np.uint8)
        cv2.fillPoly(mask, [p - (j0, i0) for p in polys], 1)
        seen = mask.astype(bool) & geo.known[i0:i1, j0:j1]
        n = int(seen.sum())
        if n < 50:
            return 0.0
        return float((seen & geo.obstacle[i0:i1, j0:j1]).sum() / n)

    # ------------------------------------------------------------------ after the match
    def check(self, state, step: int = 0, episode=None) -> bool:
        """Check the standing relocation: every ``reverify_interval`` steps against geometry
        (with the scans gathered since, which also refines the transform) and, given the
        ``episode``'s model so far, against evidence of absence (:meth:`object_absence`, as
        before a merge); every step against landmarks (this state's detections). Returns
        False (and undoes it) when any refutes it."""
        r = self.relocation
        c = self.config
        if r is None:
            return False
        if (c.geometry and c.reverify_interval > 0
                and step - r.step >= c.reverify_interval
                and (step - r.step) % c.reverify_interval == 0):
            v = self.verify(r.model_id, r.transform)
            if v.ok:
                r.transform = v.transform
            elif v.conflicts > 2 * c.max_conflicts or (v.reason != "few points"
                                                      and v.inliers < c.min_inliers / 2):
                return self._undo("undone by geometry")  # clearly wrong, not just imprecise
            if (episode is not None and c.absence_views > 0 and c.landmark_radius > 0
                    and self._absent(episode, r.model_id, r.transform)):
                # a wrong house's room leads the agent to goals that are not there
                return self._undo("undone by absence")
        if c.landmark_radius <= 0:
            return True
        xy, cls = self._landmarks
        if len(cls):
            for det in state.detections:
                x, y = se2.apply_to_point(r.transform, *det.position[:2])
                near = np.hypot(xy[:, 0] - x, xy[:, 1] - y) <= c.landmark_radius
                if near.any():
                    r.checked += 1
                    r.supported += bool((cls[near] == det.cls).any())
        if not self.refuted(r, c.verify_support):
            return True
        return self._undo("undone by landmarks")

    def _undo(self, why: str) -> bool:
        self.decisions[why] += 1
        if self.relocation.source == "scan search":
            # a model the walls fitted and the episode then refuted is most likely another
            # house's: searching it again would find the next look-alike room in it
            self._search_refuted.add(self.relocation.model_id)
        self.undone.append(self.relocation)
        self.relocation = None
        self._pairs, self._candidates = [], []
        return False

    def refuted(self, r: Relocation, share: float) -> bool:
        """Enough landmark checks (``verify_checks``), and fewer than ``share`` support ``r``."""
        need = self.config.verify_checks
        return need > 0 and r.checked >= need and r.supported < share * r.checked

    def refine(self, state) -> None:
        """Without geometric verification, correct the transform with landmarks (with it,
        re-verification aligns the scans, which is more precise): each object seen after the
        match is paired
        with the nearest remembered object of its class; every few pairs the rigid transform
        that best maps them (least squares, one round of outlier rejection) replaces the
        current one unless it moves implausibly far."""
        r = self.relocation
        c = self.config
        if r is None or c.landmark_radius <= 0 or c.geometry:
            return  # with geometry, re-verification refines: landmark positions are noisier
        stored = self.memory.model(r.model_id)
        for det in state.detections:
            x, y = se2.apply_to_point(r.transform, *det.position[:2])
            hit = stored.nearest_object(det.cls, x, y, c.landmark_radius)
            if hit is not None:
                o = stored.graph.nodes[hit]
                self._pairs.append((det.position[0], det.position[1], o["x"], o["y"], hit))
        self._pairs = self._pairs[-c.refine_pairs:]
        if len({p[4] for p in self._pairs}) < 3 or len(self._pairs) % 5:
            return
        pts = np.array([p[:4] for p in self._pairs], float)
        new = se2.fit_points(pts[:, :2], pts[:, 2:])
        res = np.hypot(*(se2.apply_to_points(new, pts[:, :2]) - pts[:, 2:]).T)
        keep = res <= max(0.5, 2.0 * float(np.median(res)))
        if keep.sum() >= 3:
            new = se2.fit_points(pts[keep, :2], pts[keep, 2:])
        at = r.at
        moved = math.dist(se2.apply_to_point(new, *at), se2.apply_to_point(r.transform, *at))
        if moved <= 1.5 and se2.angle_diff(new[2], r.transform[2]) <= math.radians(30):
            r.transform = tuple(float(v) for v in new)

    def _bridge(self, state) -> None:
        """A verified match into another stored model than the one relocated into."""
        # the models not relocated into are few states among many: look further down the list
        for m in self._matches(state.features, 8 * self.config.top_k):
            self.matched.add(m.model_id)
            if m.model_id == self.relocation.model_id or m.model_id in self.bridges:
                continue
            stored = self.memory.model(m.model_id)
            T = se2.anchor_transform(stored.pose(m.state_id), state.pose)
            v = self.verify(m.model_id, T)
            if v.ok:
                self.bridges[m.model_id] = v
                self.decisions["bridge"] += 1


#: What became of a hypothesis judged in the loop (:attr:`Relocalizer.hypotheses`): refused
#: by its geometry (the verification's reasons), verified but not yet confirmed by a second
#: match, ambiguous, refused by the episode's objects (a scan search's), verified but another
#: was taken, or accepted.
HYPOTHESIS_OUTCOMES = ("few points", "geometry", "conflict", "awaiting confirmation",
                       "ambiguous", "refused by the episode", "verified", "accepted")


def _outcome(judged: list | None, outcome: str) -> None:
    if judged is not None:
        judged[-1] = outcome


def _constraint(geo: StoredGeometry, ends: np.ndarray, T, inlier_distance: float) -> float:
    """How well the stored obstacles pin the points ``ends`` (mapped by ``T``) in every
    direction: the smaller over the larger eigenvalue of the alignment's translational
    information (the sum of n nᵀ over the inliers' distance-field normals n). 1 for walls of
    every direction, near 0 along a single wall, where an alignment slides freely."""
    pts = se2.apply_to_points(T, ends)
    d, gx, gy = geo.sample(pts)
    use = d <= inlier_distance
    if use.sum() < 3:
        return 0.0
    n = np.stack([gx[use], gy[use]], axis=1)
    lo, hi = np.linalg.eigvalsh(n.T @ n)
    return float(lo / hi) if hi > 0 else 0.0


def _margin(v: Verdict) -> float:
    return v.inliers - v.conflicts


def _alternatives(T, centre):
    """Starting transforms around ``T`` for the ambiguity test: ``T`` shifted (model frame)
    by 0.75 and 1.5 m in eight directions, and turned about ``centre`` by 90, 180, 270°."""
    for d in (0.75, 1.5):
        for k in range(8):
            a = k * math.pi / 4
            yield se2.compose((d * math.cos(a), d * math.sin(a), 0.0), T)
    cx, cy = float(centre[0]), float(centre[1])
    for k in (1, 2, 3):
        turn = se2.compose((cx, cy, k * math.pi / 2), (-cx, -cy, 0.0))
        yield se2.compose(turn, T)


def _spread(pts: np.ndarray) -> float:
    """The smaller standard deviation of a point set (0 for points along one line)."""
    if len(pts) < 3:
        return 0.0
    return float(np.sqrt(max(np.linalg.eigvalsh(np.cov(pts.T))[0], 0.0)))


