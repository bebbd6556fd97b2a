//! Every WGSL module the render core builds is parsed and validated by naga, with all
//! capabilities, so a broken shader fails here without a GPU.

#[test]
fn every_shader_parses_and_validates() {
    let mut failures = Vec::new();
    let modules = canopy::render::shaders::all();
    assert!(
        modules.len() >= 3,
        "expected geometry, shadow and sky modules"
    );
    for (name, source) in modules {
        let module = match naga::front::wgsl::parse_str(&source) {
            Ok(m) => m,
            Err(e) => {
                failures.push(format!(
                    "{name}: parse error:\n{}",
                    e.emit_to_string(&source)
                ));
                continue;
            }
        };
        let mut validator = naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        );
        if let Err(e) = validator.validate(&module) {
            failures.push(format!(
                "{name}: validation error:\n{}",
                e.emit_to_string(&source)
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

#[test]
fn every_shader_file_is_used() {
    // A WGSL file in shaders/ that no module includes would never be validated.
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let all: String = canopy::render::shaders::all()
        .into_iter()
        .map(|(_, s)| s)
        .collect();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "wgsl") {
            let text = std::fs::read_to_string(&path).unwrap();
            assert!(
                all.contains(text.trim()),
                "{} is not part of any shader module",
                path.display()
            );
        }
    }
}
