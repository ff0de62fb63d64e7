// Registration of the model module's components (called from
// RegisterBuiltins() in framework/framework.cc). Declared here, away from the
// torch module headers, so that registering costs no torch include.
#pragma once

namespace soma {

/// Registers everything below.
void RegisterModelComponents();

/// Backbone specs `self_attention` and `conv1d` (registry kind "backbone").
void RegisterBackbones();
/// `sinkhorn` and `log_softmax` and the `normalization` config group.
void RegisterNormalizations();
/// The `soma` model spec and the `model` config group.
void RegisterModelSpecs();
/// The `soma` labelling loss and the `loss` config group.
void RegisterLosses();

}  // namespace soma
