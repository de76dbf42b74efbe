"""Appearance: a simulated paint's full gonio BRDF and the car-paint model renderers use.

In: a paint (a reference sample with overrides, as `paintjax.simulate` takes it). Out: its
`GonioTable` (the tracer's reflectance factor over incidences 0–80° and outgoing directions in and
out of the plane, every MA98 geometry included, each with a statistical error) and a fitted
`CarPaintBRDF` (diffuse + up to three Cook–Torrance lobes under a clearcoat, times an AxF-style
colour table χ(θh, θd)) with its ΔL* report,
exported as a documented JSON file (docs/appearance.md) that `paintjax.render` draws in Mitsuba 3.
"""

from ._carpaint import CarPaintBRDF, load_car_paint
from ._carpaint_fit import CarPaintFit, car_paint_for_sample, fit_car_paint
from ._gonio import GonioTable, gonio_table, ma98_geometries
from ._plots import plot_car_paint_fit

__all__ = ["CarPaintBRDF", "load_car_paint", "CarPaintFit", "car_paint_for_sample", "fit_car_paint", "plot_car_paint_fit", "GonioTable", "gonio_table", "ma98_geometries"]
