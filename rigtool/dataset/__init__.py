"""The lab-wide Parquet dataset `rigtool export --all DIR` keeps: one Hive partition per run
(thruster_id=<id>/run_id=<id>/samples.parquet), a manifest, a runs and a calibrations table,
updated incrementally (docs/sql.md). One job a module: `hive` (folder names), `files`
(atomic writes, the lock), `partition` (one run's file), `calibrations` (a run's coefficient
rows), `tables` (the runs and calibrations tables), `manifest`, `update` (the export)."""
