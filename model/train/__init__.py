"""Training commands for the VideoTok4D networks."""
