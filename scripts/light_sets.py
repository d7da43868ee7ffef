#!/usr/bin/env python3
"""Seeded random light sets for a scene (the figures scripts' shared generator).

Usage: light_sets.py SCENE.json NAME COUNT PREFIX
Writes PREFIX0.json … PREFIX{COUNT-1}.json: set i draws 1–4 point lights, each in a random
block at least 0.3 m from its walls and from every clutter box, with an intensity of 2–20
(slightly different per channel), from random.Random(1000 · len(NAME) + i), so a set is the
same whichever script asks for it.
"""
import json
import random
import sys


def main():
    scene_path, name, count, prefix = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    s = json.load(open(scene_path))
    boxes = [c["box"] for c in s.get("clutter", []) if "box" in c]

    def clear(p):
        for b in boxes:
            if all(b["min"][k] - 0.3 < p[k] < b["max"][k] + 0.3 for k in range(3)):
                return False
        return True

    for i in range(count):
        rng = random.Random(1000 * len(name) + i)
        lights = []
        for _ in range(1 + rng.randrange(4)):
            for _ in range(1000):
                b = rng.choice(s["blocks"])
                p = [rng.uniform(b["min"][k] + 0.3, b["max"][k] - 0.3) for k in range(3)]
                if clear(p):
                    break
            base = rng.uniform(2.0, 20.0)
            lights.append({"kind": "point", "position": p,
                           "intensity": [base * rng.uniform(0.8, 1.0) for _ in range(3)]})
        json.dump({"lights": lights, "poses": []}, open(f"{prefix}{i}.json", "w"), indent=1)


if __name__ == "__main__":
    main()
