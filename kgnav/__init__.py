"""kgnav: reusable Abstract Models for Object Goal Navigation."""

__version__ = "0.1.0"
