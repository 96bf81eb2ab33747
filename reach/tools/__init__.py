"""Tools for people: the command line, reports and figures, the 3-D viewer and its gate, sketches and exports."""
