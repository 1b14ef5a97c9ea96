"""The CiA 301/302 vocabulary, with no pipeline state: NMT commands and states, SDO and
EMCY frames, device files (EDS/DCF). Everything below the timeline may import it."""
