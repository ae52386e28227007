"""`sofia noise`: a gyro-stability bag analyzed the way 5.2 does (docs/noise.md), laid out like compare/.

cli (the command line), run (load the record and analyze it: Earth rate, Allan, PSD, lines, the loop),
earth_rate (Table 5.7), fit (the noise terms' Allan and PSD curves and the five-term fit, 4.2),
measure / predict / candidates (the noise-model loop: what the record measured, what a model
predicts, the missing terms ranked), report (the HTML page with the plots of Figs. 5.5-5.17).
"""
