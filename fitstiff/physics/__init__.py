"""The physics, differentiable in JAX: the polytropic gas spring, the transform layer of parameters,
a log's drive, the terms (chamber, friction laws, modifiers, additive forces), their composition
into a model, the derived quantities, the stiffness calculator, programs and the simulator."""
