"""What a run measures about itself while it runs: peak memory per keyframe window, time per phase, progress."""
