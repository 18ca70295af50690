//! The static diagnosis' fit screen (`statics::screen`) against the full search it replaces: on a
//! specimen with a stiff inclusion, one round on the dataset's own mesh, both ways.

use crate::support::drawn;
use palpate_diagnose::model::Candidate;
use palpate_diagnose::{run_diagnosis, DiagnoseOptions, MeshChoice};
use palpate_specimen::{Effect, SpecimenOptions};

/// The screened round adopts what the full search adopts, at the same fitted and held-out
/// figures (the adopted candidate's fit is the same computation), fits fewer candidates and
/// lists the others as screened out with their prediction; its prediction of the winner is the
/// fit's ΔBIC within a few per cent (measured: −682.0 predicted, −685.9 fitted); and a candidate
/// that acts on the solved markers only is fitted unpredicted.
#[test]
fn the_screen_adopts_what_the_full_search_adopts_with_fewer_fits() {
    let s = drawn(&SpecimenOptions::with_effect(Some(Effect::Inclusion), 1)).expect("specimen");
    let o = DiagnoseOptions {
        max_effects: 1,
        mesh: MeshChoice::Dataset,
        ..Default::default()
    };
    assert!(o.screen, "the screen is the default");
    let screened = run_diagnosis(&s.dataset, &o).expect("screened diagnosis");
    let full = run_diagnosis(
        &s.dataset,
        &DiagnoseOptions {
            screen: false,
            ..o.clone()
        },
    )
    .expect("full search");
    assert_eq!(screened.adopted, full.adopted);
    assert_eq!(screened.adopted.first(), Some(&Candidate::Inclusion));
    assert_eq!(screened.after.fitted_rms, full.after.fitted_rms);
    assert_eq!(screened.after.heldout_rms, full.after.heldout_rms);

    let (scr, all) = (&screened.steps[0].tried, &full.steps[0].tried);
    assert_eq!(scr.len(), all.len(), "every open candidate is listed");
    let fitted = scr.iter().filter(|t| t.not_fitted.is_none()).count();
    let out: Vec<_> = scr.iter().filter(|t| t.screened_out).collect();
    assert!(
        fitted < all.iter().filter(|t| t.not_fitted.is_none()).count() && !out.is_empty(),
        "screened: {fitted} fitted, {} screened out",
        out.len()
    );
    assert!(out
        .iter()
        .all(|t| t.predicted_delta_bic.is_some() && t.delta_bic.is_nan()));
    assert!(all
        .iter()
        .all(|t| !t.screened_out && t.predicted_delta_bic.is_none()));
    let winner = scr
        .iter()
        .find(|t| t.candidate == Candidate::Inclusion)
        .expect("inclusion tried");
    let predicted = winner.predicted_delta_bic.expect("predicted");
    assert!(
        (predicted / winner.delta_bic - 1.0).abs() < 0.05,
        "inclusion: predicted ΔBIC {predicted:.1}, fitted {:.1}",
        winner.delta_bic
    );
    let marker_side = scr
        .iter()
        .find(|t| t.candidate == Candidate::Registration)
        .expect("registration tried");
    assert!(
        marker_side.predicted_delta_bic.is_none() && marker_side.not_fitted.is_none(),
        "registration: {:?}",
        marker_side.not_fitted
    );
}
