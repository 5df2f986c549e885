"""The ``clutt3r`` commands of the core: tyro functions, kept apart from the algorithm modules."""
