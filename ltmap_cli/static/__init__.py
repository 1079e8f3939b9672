"""Static map S from an architect's plan: SVG parsing (svgplan), rasterization (rasterize), and
the build of the 2D map and 3D static layer (build). See docs/plans.md."""
