"""A model's class inventory, and what is visible from one of its states.

    python queries/inventory_and_views.py MODEL_ID [--state s0] [--store DIR]
"""

from _common import open_store, parser, run

from kgnav import query


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("model_id")
    p.add_argument("--state", default="s0", help="state id (default s0)")
    args = p.parse_args()
    model = open_store(args.store).load(args.model_id)
    for cls, counts in query.class_inventory(model).items():
        print(f"{cls}: {counts['objects']} objects, {counts['views']} views")
    x, y, theta = model.pose(args.state)
    print(f"from {args.state} at ({x:.2f}, {y:.2f}, {theta:.2f} rad):")
    for obj in query.visible_from(model, args.state):
        print(f"  {obj.cls} {obj.id} at ({obj.position[0]:.2f}, {obj.position[1]:.2f})")


if __name__ == "__main__":
    run(main)
