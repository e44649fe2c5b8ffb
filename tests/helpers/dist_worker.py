"""Run under torchrun by tests/test_distributed.py: train a few steps data-parallel; rank 0 writes the run's
summary (which says whether every rank ended with identical parameters) to the JSON file in argv[3]."""

import json
import os
import sys

from lift3d.train.trainer import train

scene, out, report = sys.argv[1], sys.argv[2], sys.argv[3]
overrides = json.loads(sys.argv[4])
result = train(scene, preset="fast", output_dir=out, overrides=overrides, progress=False, print_summary=False)
if int(os.environ.get("RANK", "0")) == 0:
    with open(report, "w") as f:
        json.dump({"run": str(result.run.path), "summary": result.summary}, f, default=str)
