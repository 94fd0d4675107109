"""Run files from and to other tools' formats: a bench tool's CAN log imported
(`import_log`), a run file's channels exported as ASAM MDF 4 (`export_mdf`), and the
clean-up after a third-party reader that failed to open a file (`failed_open`)."""
