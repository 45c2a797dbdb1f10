"""File input and output: raw mosaics, images, atomic writes."""
