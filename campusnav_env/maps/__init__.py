"""Maps: road graphs (generated campus, OpenStreetMap imports, scene files), compass slots and closures."""
