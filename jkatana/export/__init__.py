"""Scenes and fitted materials out to other renderers: Mitsuba 3, glTF 2.0 and pbrt-v4 (``jkatana export``)."""
