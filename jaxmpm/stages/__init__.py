"""The stages of one explicit step (PHYSICS 2.1) and the Layout they share; composed by
`jaxmpm.step.make_step`."""
