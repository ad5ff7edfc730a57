"""Relocate a new episode's model in the memory and merge it into the matched model.

    python queries/relocate_and_merge.py EPISODE.graphml [--threshold 0.3] [--save] [--store DIR]

States are tried in order (as the agent meets them); the first match below the threshold
anchors the merge. With --save the merged model replaces the stored one.
"""

from _common import open_store, parser, run

from kgnav import AbstractModel, Relocator, merge


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("episode", help="GraphML file of the new episode's model")
    p.add_argument("--threshold", type=float, default=0.3)
    p.add_argument("--save", action="store_true", help="write the merged model to the store")
    args = p.parse_args()
    store = open_store(args.store)
    current = AbstractModel.load(args.episode)
    relocator = Relocator(threshold=args.threshold).fit(store)
    ids, feats = current.state_features()
    for state, f in zip(ids, feats, strict=True):
        match = relocator.match(f)
        if match is None:
            continue
        merged = merge(store.load(match.model_id), current, anchor=(match.state_id, state))
        print(f"{state} matches {match.model_id}/{match.state_id} "
              f"(cosine distance {match.distance:.3f}); merged: {merged.n_states} states, "
              f"{merged.n_objects} objects")
        if args.save:
            print(f"saved {store.save(merged)}")
        return
    print(f"no state of {current.model_id} matches the memory: a new environment")


if __name__ == "__main__":
    run(main)
