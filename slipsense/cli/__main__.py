"""``python -m slipsense.cli ...`` (what torchrun runs: ``torchrun ... -m slipsense.cli train ...``)."""

from slipsense.cli import main

if __name__ == "__main__":
    main()
