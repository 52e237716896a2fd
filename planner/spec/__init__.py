"""What the spec talks about: regions (boxes, prisms, cylinders and their polygon covers), the
predicates over them (``inside``, ``outside``, ``dist``, ...), their geometry, and the heading
and camera windows that ``face`` asks for.  Import the modules directly."""
