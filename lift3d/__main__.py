"""``python -m lift3d`` (also what ``torchrun -m lift3d`` runs)."""

from lift3d.cli.main import main

if __name__ == "__main__":
    raise SystemExit(main())
