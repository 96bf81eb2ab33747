"""The map and its files: the VATree, the reachability index, the ReachMap protocol they answer through, and the
atlas folder that stores them."""
