"""Hair on a head: roots on a scalp, dense hair from guides, guide picking, hair and USD files, the sag-free start."""
