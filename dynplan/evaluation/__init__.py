"""Evaluation over recorded episodes (the paper's Table 1 protocol) and its aggregation."""
