"""The places file (named stands and targets in the map frame): one reader for every
service, :mod:`quadmanip.common.places`; re-exported here for navigation's modules."""

from quadmanip.common.places import (
    KINDS,
    TABLE_KINDS,
    Place,
    PlacesError,
    load_places,
    places_path_for,
    save_places,
)

__all__ = [
    "KINDS",
    "TABLE_KINDS",
    "Place",
    "PlacesError",
    "load_places",
    "places_path_for",
    "save_places",
]
