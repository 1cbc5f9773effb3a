"""Training: the window data set, the training loop, losses, augmentation and the ablation."""
