"""Settings of the diagnosis shared by its modules (levels, folds, limits)."""

ALPHA = 0.01
"""Level of the goodness-of-fit test and family-wise level of each selection step."""
MIN_REMAINING = 0.05
"""A candidate whose columns keep less than this fraction outside the model's span is 'absorbed'."""
K_FOLDS = 5
"""Folds of the cross-validation over poses."""
MAX_EFFECTS = 4
"""Most effects the stepwise selection adds."""
FOLD_SEED = 0
"""Seed of the random assignment of poses to folds."""
