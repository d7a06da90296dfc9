"""train_karras — Karras et al. 2017 (paper 001): autocorrelation conv net with learned emotions (in progress)."""
