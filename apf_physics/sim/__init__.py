"""Where robots are stepped: pymunk discs among a world's obstacles (``physics``), what touched what
(``contacts``), each world's static geometry in the one space (``tiles``), exact swept distances
(``swept``), and the episode stepper that every environment, rollout and trainer calls (``engine``)."""
