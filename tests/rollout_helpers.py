"""What the rollout tests share (tests/test_rollout.py, test_batch_rollout.py, test_ray.py): a scene
variant and the CSV reader of their logs and summaries."""

import csv

import physhand_mj as ph

APPLE = ph.scene_path("hoi_apple")


def apple_b(tmp):
    """hoi_apple with its hand 1 mm further along y and 1 mm lower: the same objects, another grasp
    (written to ``tmp``/apple_b.xml)."""
    text = APPLE.read_text().replace('file="../hand/', f'file="{APPLE.parent.parent / "hand"}/')
    old = 'mpos="-0.0816409 -0.0143553 0.202622"'
    assert old in text
    path = tmp / "apple_b.xml"
    path.write_text(text.replace(old, 'mpos="-0.0816409 -0.0133553 0.201622"'))
    return path


def read_csv(path):
    """The rows of a rollout's log.csv or summary.csv as dicts of strings."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
