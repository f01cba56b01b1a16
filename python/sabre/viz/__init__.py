"""What a person looks at: the browser viewer (:mod:`sabre.viz.viewer`, the ``viewer`` extra) and the
episode figure (:mod:`sabre.viz.plots`, the ``plot`` extra); neither extra is imported until used."""
