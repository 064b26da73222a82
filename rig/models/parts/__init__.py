"""The parts every model is built from: parameters with bounds and units (`Param`), the components
(`BaseModel`, `Effect`) and their registry, the prediction they change, its derivatives, a fit's result."""
