"""The shortest action sequence between two states of a model, along its transitions.

    python queries/action_path.py MODEL_ID FROM_STATE TO_STATE [--store DIR]
"""

from _common import open_store, parser, run

from kgnav import query


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("model_id")
    p.add_argument("start")
    p.add_argument("goal")
    args = p.parse_args()
    model = open_store(args.store).load(args.model_id)
    path = query.action_path(model, args.start, args.goal)
    if path is None:
        print(f"no path from {args.start} to {args.goal}")
    else:
        print(f"{len(path)} actions: {' '.join(path) or '(already there)'}")


if __name__ == "__main__":
    run(main)
