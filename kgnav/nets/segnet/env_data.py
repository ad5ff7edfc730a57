"""Labelled frames of any registered environment, for training and measuring the segmenter.

kgnav's simulator renders a labelled view from any pose (:class:`~kgnav.nets.segnet.data.
LabelledViews`); another simulator offers only ``reset`` and ``step``. So the frames come from
seeded random walks through the environment protocol
(:func:`~kgnav.nets.encoder.env_views.walk_scene`, the encoder's walks), asking for the
``semantic`` frame: the environment's ground truth is read here, at training and benchmark
time, never by the agent. :class:`EnvLabelledViews` then serves batches as ``LabelledViews``
does: ``object_share`` of the frames show an object of a uniformly drawn class the scene's
walks saw (class-balanced, as aimed views are), the rest are drawn uniformly.

The same arguments give the same frames (the walks are seeded, the environments are), so a
training run on them is as reproducible and resumable as one on kgnav's houses.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from kgnav.errors import KgnavError

#: A frame shows a class when at least this many of its pixels have it (the segments the agent
#: keeps are at least 20 pixels).
SHOWS_PIXELS = 50


class EnvLabelledViews:
    """Walked views with their semantic frames (``views``: one
    :class:`~kgnav.nets.encoder.env_views.SceneViews` per scene, ``semantic`` present) in an
    environment whose vocabulary is ``classes``."""

    def __init__(self, views: Sequence, classes: Sequence[str]):
        if not views:
            raise KgnavError("no scenes to draw labelled frames from")
        self.views = list(views)
        self.scenes = self.views  # ``.name`` per scene, as LabelledViews' scenes have
        self.classes = tuple(classes)
        k = len(self.classes) + 1
        self.by_class: list[dict[int, np.ndarray]] = []  # per scene: class id -> frames
        for v in self.views:
            if v.semantic is None:
                raise KgnavError(f"scene {v.name!r} was walked without its semantic frames")
            cls = v.semantic[..., 0].reshape(len(v.semantic), -1)
            if int(cls.max(initial=0)) >= k:
                raise KgnavError(f"scene {v.name!r}: class id {int(cls.max())} outside the "
                                 f"environment's {len(self.classes)} classes")
            counts = np.stack([np.bincount(c, minlength=k) for c in cls])
            self.by_class.append({c: np.flatnonzero(counts[:, c] >= SHOWS_PIXELS)
                                  for c in range(1, k) if (counts[:, c] >= SHOWS_PIXELS).any()})

    @classmethod
    def from_suite(cls, suite, scenes: Sequence[int], steps: int, seed: int = 0,
                   episodes: int = 4, progress: Callable[[int, int], None] | None = None
                   ) -> EnvLabelledViews:
        """Walk ``steps`` labelled views in each of ``scenes`` of an environment's suite (the
        encoder's walks, :meth:`EnvViewSampler.from_suite
        <kgnav.nets.encoder.env_views.EnvViewSampler.from_suite>`, with the labels kept)."""
        from kgnav.nets.encoder.env_views import walk_scene

        if not scenes:
            raise KgnavError(f"environment {suite.name!r} has no scenes to walk")
        views, classes = [], None
        for n, k in enumerate(scenes):
            env = suite.make(k, episodes)
            classes = classes or env.env_spec.classes
            name = str(getattr(env, "scene_name", None) or f"{suite.name}-{k:02d}")
            views.append(walk_scene(env, name, steps, min(episodes, suite.episode_count(k)),
                                    seed, k, semantic=True))
            if progress is not None:
                progress((n + 1) * steps, len(scenes) * steps)
        return cls(views, classes)

    def __len__(self) -> int:
        return len(self.views)

    def frame(self, house: int, rng: np.random.Generator, object_share: float) -> int:
        """A frame index of scene ``house``: showing an object of a uniformly drawn class with
        probability ``object_share`` (when the scene's walks saw one), else any."""
        shown = self.by_class[house]
        n = len(self.views[house].rgb)
        if rng.random() < object_share and shown:
            frames = shown[list(shown)[int(rng.integers(len(shown)))]]
            return int(frames[rng.integers(len(frames))])
        return int(rng.integers(n))

    def frames(self, rng: np.random.Generator, n: int, houses: Sequence[int] | None = None,
               object_share: float = 0.75):
        """``n`` labelled frames from ``houses`` (default: all, round robin after a shuffle):
        (rgb (n, H, W, 3), depth (n, H, W), semantic int32 (n, H, W, 2), houses (n,),
        poses (n, 3)), as :meth:`LabelledViews.frames <kgnav.nets.segnet.data.LabelledViews.
        frames>` returns them."""
        hs = list(range(len(self))) if houses is None else list(houses)
        order = [hs[int(i)] for i in rng.permutation(len(hs))]
        picks = []
        for k in range(n):
            h = order[k % len(order)]
            picks.append((h, self.frame(h, rng, object_share)))
        v = self.views
        return (np.stack([v[h].rgb[i] for h, i in picks]),
                np.stack([v[h].depth[i].astype(np.float32) for h, i in picks]),
                np.stack([v[h].semantic[i].astype(np.int32) for h, i in picks]),
                np.array([h for h, _ in picks]),
                np.array([v[h].poses[i] for h, i in picks], float))

