"""Everything rigtool writes to disk for a calibration, with one atomic writer and one JSON/CSV
convention (rigtool.artefacts.write); `state` is the stored form a report renders from."""
