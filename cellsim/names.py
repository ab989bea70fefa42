"""The public names of ``import cellsim`` (:mod:`cellsim.api`'s), in a module of their own that imports nothing:
``import cellsim`` (and the command line, which imports it first) reads them without loading the API, so that
nothing heavy is imported before a command has its signal handlers."""

PUBLIC = [
    "BlackBoxError", "CONFIDENCE", "COUNT_LIMITS", "CampaignConfig", "CampaignError", "CellBuild", "CellDiagram", "CellSystem", "CheckError",
    "ConfigError", "ConfigurationPoint", "DEFAULT_SEARCH", "EXPLICIT_LIMIT", "Fixture", "FoxgloveFeed", "Layout",
    "Live", "OutputExistsError", "OverwritesInput", "Region", "Run", "SEARCH_METHODS", "Scenario", "ScenarioFile", "Validation",
    "Verdict", "VerifyError", "build", "check", "check_campaign", "check_duration", "check_seed",
    "compile_conditions", "default_conditions", "export_trace", "falsify", "formula_and_description", "is_campaign",
    "kind_config", "load_scenario", "module", "open_meshcat", "robustness", "run_campaign", "runs_folder",
    "runs_needed", "save_scenario", "scenario_in_code", "scenario_yaml", "simulate", "verify_cell",
]
