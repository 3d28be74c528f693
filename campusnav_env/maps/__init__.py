"""Maps: road graphs (generated campus, OpenStreetMap imports, scene files), compass slots and closures, how large a
map may be for its street views (:mod:`~campusnav_env.maps.extent`) and the example files shipped with the package
(:mod:`~campusnav_env.maps.examples`)."""
