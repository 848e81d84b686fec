"""hydroplant simulation layer."""
