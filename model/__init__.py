"""vt4dcodec.model: the VideoTok4D networks."""
