"""Shared argument handling for the query examples: every example reads a model store."""

from __future__ import annotations

import argparse
import sys

from kgnav import KgnavError, ModelStore

DEFAULT_STORE = "export/demo/memory"


def parser(description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--store", default=DEFAULT_STORE, help=f"model store (default {DEFAULT_STORE})")
    return p


def open_store(path: str) -> ModelStore:
    store = ModelStore(path)
    if not store.ids():
        sys.exit(f"{path}: no models here (build one with: kgnav demo)")
    return store


def run(main) -> None:
    """Run ``main()`` turning kgnav errors into one line and exit status 1."""
    try:
        main()
    except KgnavError as exc:
        sys.exit(f"error: {exc}")
