//! What a stage trains: the kind a training manifest's `[[stages]]` entry names, which decides
//! the step it runs and the loss terms it uses (each term says which kinds use it: `loss`).

use serde::{Deserialize, Serialize};

/// What a stage trains.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StageKind {
    /// Normal and material modules alone, L2 losses only (Sec. 4: "pre-trained using L2 loss").
    /// A model stopped after this stage is the paper's *standalone* baseline of Tables 1 and 2.
    Pretrain,
    /// The modules through the rendering layer with the joint loss of Eq. 5.
    Joint,
    /// Baseline 1 of Sec. 4.5 (after Kulkarni et al.): the encoder–decoder alone, with the L2
    /// loss on f_m (w_m) and the perceptual loss on its O' (w_p, and w_s when set); no rendering.
    EncoderDecoder,
}
