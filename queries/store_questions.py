"""Questions asked of every model of a store at once (Cypher on a graph database, networkx on
a directory: the same answers).

    python queries/store_questions.py [--store STORE] objects CLASS [--min-views N]
    python queries/store_questions.py [--store STORE] near CLASS_A CLASS_B METRES
    python queries/store_questions.py [--store STORE] saw MODEL_ID OBJECT_ID
    python queries/store_questions.py [--store STORE] inventory
    python queries/store_questions.py [--store STORE] within MODEL_ID STATE_ID HOPS

STORE is a directory of GraphML files or a database (``kgnav store convert DIR memory.lbug``).
"""

from _common import open_store, parser, run

from kgnav import query


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="question", required=True)
    o = sub.add_parser("objects", help="every object of a class, with its evidence")
    o.add_argument("cls")
    o.add_argument("--min-views", type=int, default=1)
    n = sub.add_parser("near", help="the models holding class A within METRES of class B")
    n.add_argument("a")
    n.add_argument("b")
    n.add_argument("metres", type=float)
    s = sub.add_parser("saw", help="the states that saw an object, nearest first")
    s.add_argument("model_id")
    s.add_argument("object_id")
    sub.add_parser("inventory", help="objects per class of every model")
    w = sub.add_parser("within", help="objects seen within HOPS transitions of a state")
    w.add_argument("model_id")
    w.add_argument("state_id")
    w.add_argument("hops", type=int)
    args = p.parse_args()
    store = open_store(args.store)
    if args.question == "objects":
        for ob in query.find_objects(store, args.cls, args.min_views):
            x, y, _ = ob.position
            print(f"{ob.model_id} {ob.id} {ob.cls} at ({x:.2f}, {y:.2f}): {ob.n_views} views, "
                  f"{ob.n_obs} detections, score {ob.score:.2f}")
    elif args.question == "near":
        for model_id in query.models_with_classes_near(store, args.a, args.b, args.metres):
            print(model_id)
    elif args.question == "saw":
        for state, dist in query.states_that_saw(store, args.model_id, args.object_id):
            print(f"{state} at {dist:.2f} m")
    elif args.question == "inventory":
        for model_id, inv in query.class_inventories(store).items():
            print(f"{model_id}: " + ", ".join(f"{c} {k}" for c, k in inv.items()))
    else:
        print(" ".join(query.objects_near_state(store, args.model_id, args.state_id, args.hops)))


if __name__ == "__main__":
    run(main)
