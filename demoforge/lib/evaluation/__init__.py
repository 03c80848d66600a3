"""Measuring the stages against ground truth: the thesis's keypoint metrics and tables (``metrics``,
``keypoints``), ARCTIC (``arctic``), the labelled real photos (``real_photos``), hand detection on
synthetic takes (``detection``), and what people look at: report tables (``markdown``), plots
(``plots``) and skeleton overlays (``visualize``). Plain rows for the tables of ``schemas/``."""
