"""The paper's two studies (``python -m experiments.rq1`` and ``python -m experiments.rq2``) and the
command lines to train and evaluate one agent (``experiments.train``, ``experiments.evaluate``)."""
