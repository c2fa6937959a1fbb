"""The functional env API (``core``), spaces, wrappers, batched stepping, the id registry and the
probe MDPs that test learners."""
