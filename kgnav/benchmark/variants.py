"""The benchmark's agent variants (paper, "Reusing Abstract Models" and "Semantic Maps and
Abstract Models"), by name.

========  ===========================================================================
``ans``   memory-less baseline (ANS*): learns a model per episode, reuses nothing
``hp``    Hard Pre-explored: one model per house built beforehand, trusted blindly
``sp``    Soft Pre-explored: the same models, soft strategy
``si``    Soft Incremental: no prior knowledge; models learned, stored and merged over
          episodes (the paper's full method)
``sem+si`` SI on the goal-directed semantic frontier policy (SemExp*+SI analogue)
``oracle`` ground-truth map and pose, shortest path: the upper bound
========  ===========================================================================
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from kgnav.errors import KgnavError


@dataclass(frozen=True)
class Variant:
    name: str
    memory: str | None = None  # None, "pre" (pre-explored models) or "incremental"
    strategy: str = "soft"
    policy: str = "frontier"
    oracle: bool = False

    @property
    def learns(self) -> bool:
        """Whether its episodes write back into its memory."""
        return self.memory == "incremental"


VARIANTS: dict[str, Variant] = {
    v.name: v
    for v in (
        Variant("ans"),
        Variant("hp", memory="pre", strategy="hard"),
        Variant("sp", memory="pre", strategy="soft"),
        Variant("si", memory="incremental", strategy="soft"),
        Variant("sem+si", memory="incremental", strategy="soft", policy="semantic"),
        Variant("oracle", oracle=True),
    )
}


def with_policy(variant: Variant, policy: str | None) -> Variant:
    """``variant`` under ``kgnav eval --policy``: ``ans`` and ``si`` explore with ``policy``;
    ``sem+si`` keeps ``semantic`` unless ``policy`` is ``ppo-semantic``; the rest keep theirs.

    >>> with_policy(VARIANTS["si"], "ppo").policy, with_policy(VARIANTS["sem+si"], "ppo").policy
    ('ppo', 'semantic')
    """
    if policy is None:
        return variant
    if variant.name in ("ans", "si") or (variant.policy == "semantic"
                                         and policy == "ppo-semantic"):
        return replace(variant, policy=policy)
    return variant


def parse_variants(text: str) -> list[Variant]:
    """``"ans,si"`` → the variants, in the given order, without repeats."""
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise KgnavError("no variant given")
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        raise KgnavError(f"unknown variant {unknown[0]!r} (known: {', '.join(VARIANTS)})")
    return [VARIANTS[n] for n in dict.fromkeys(names)]
