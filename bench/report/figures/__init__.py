"""Every figure pocketbench draws, one module per figure family."""
