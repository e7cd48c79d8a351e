"""Conservative Q-learning, CQL(H) on a SAC base (Kumar et al. 2020; CORL ``algorithms/offline/cql.py``, JaxCQL):
``losses``, ``agent``."""
