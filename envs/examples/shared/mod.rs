// Not every example uses every helper.
#[allow(dead_code)]
pub mod adversarial;
#[allow(dead_code)]
pub mod hold;
#[allow(dead_code)]
pub mod settings;
