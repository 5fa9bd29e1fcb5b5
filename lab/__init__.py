"""The lab: analysis and validation runs (`python -m lab.…` from the checkout), outside the installed package."""
