"""Images -> window: optical flow, point tracks, instances, and the sliding window holding them."""
