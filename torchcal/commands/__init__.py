"""Sub-commands of the `torchcal` command line, one module each."""
