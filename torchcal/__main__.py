"""`python -m torchcal` runs the command line."""

if __name__ == "__main__":  # not when a "spawn" child process imports this module again
    from torchcal.cli import main

    raise SystemExit(main())
