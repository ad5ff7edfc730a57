"""Objects of a class ranked by the number of distinct states they are visible from.

    python queries/visibility_ranking.py sofa [--top 5] [--store DIR]
"""

from _common import open_store, parser, run

from kgnav import query


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("cls", help="object class")
    p.add_argument("--top", type=int, default=5, help="rows per model (default 5)")
    args = p.parse_args()
    store = open_store(args.store)
    for model_id in store.ids():
        ranked = query.ranked_objects(store.load(model_id), args.cls)[: args.top]
        print(f"{model_id}: {len(ranked)} shown")
        for rank, obj in enumerate(ranked, 1):
            print(f"  {rank}. {obj.id} views={obj.n_views} obs={obj.n_obs} "
                  f"at ({obj.position[0]:.2f}, {obj.position[1]:.2f})")


if __name__ == "__main__":
    run(main)
