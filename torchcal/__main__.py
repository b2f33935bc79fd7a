"""`python -m torchcal` runs the command line."""

from torchcal.cli import main

raise SystemExit(main())
