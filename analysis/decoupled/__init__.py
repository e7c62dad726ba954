"""Per-joint (decoupled) identification campaign of Bona & Curatella (2005), section 3."""
