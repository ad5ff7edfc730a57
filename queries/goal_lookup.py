"""Where should the agent go for a class? The paper's goal point in every stored model.

    python queries/goal_lookup.py chair --near 1.0,2.0 [--store DIR]

The goal is the closest object to --near among the five most-seen objects of the class.
"""

from _common import open_store, parser, run

from kgnav import query


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("cls", help="goal object class, e.g. chair")
    p.add_argument("--near", default="0,0", help="X,Y in each model's frame (default 0,0)")
    args = p.parse_args()
    x, y = (float(v) for v in args.near.split(","))
    store = open_store(args.store)
    models, problems = store.load_all()
    for problem in problems:
        print(f"skipped {problem}")
    for model_id, model in models.items():
        goal = query.goal_point(model, args.cls, near=(x, y))
        if goal is None:
            print(f"{model_id}: no {args.cls}")
        else:
            gx, gy, gz = goal.position
            print(f"{model_id}: {args.cls} {goal.id} at ({gx:.2f}, {gy:.2f}, {gz:.2f}), "
                  f"seen from {goal.n_views} states")


if __name__ == "__main__":
    run(main)
