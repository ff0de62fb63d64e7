#include "framework/model/labeler.h"

#include "framework/body/vertex_descriptors.h"
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/model/register.h"
#include "framework/model/torch_utils.h"
#include "framework/registry/registry.h"

#include <fmt/format.h>
#include <torch/torch.h>

#include <limits>
#include <utility>
#include <vector>

namespace soma {

void LabelerOptions::Validate() const {
  auto fail =
      [](std::string_view key, int64_t value, std::string_view constraint) {
        throw ConfigError(fmt::format(
            "Invalid configuration. {} = {}. Violated constraint: {}",
            key,
            value,
            constraint));
      };
  if (num_labels <= 0) fail("num_labels", num_labels, "num_labels > 0");
  if (d_model <= 0) fail("d_model", d_model, "d_model > 0");
  if (hidden <= 0) fail("hidden", hidden, "hidden > 0");
  if (conditioned) {
    label_encoder.Validate();
    if (label_encoder.d_model != d_model) {
      fail("label_encoder.d_model", label_encoder.d_model, "== d_model");
    }
  }
  if (cross_layers < 0 || (cross_layers > 0 && !conditioned)) {
    fail("cross_layers",
         cross_layers,
         "cross_layers >= 0, and 0 unless the labeller is conditioned "
         "(model=soma_any_layout)");
  }
  if (!(position_loss >= 0.0) || (position_loss > 0.0 && !conditioned)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. position_loss = {}. Violated constraint: "
        "position_loss >= 0, and 0 unless the labeller is conditioned "
        "(model=soma_any_layout)",
        position_loss));
  }
}

at::Tensor MedianOffsets(const at::Tensor& points) {
  if (points.dim() != 3 || points.size(2) != 3) {
    throw ShapeError(
        fmt::format("MedianOffsets: points must be B x N x 3, got {}",
                    ShapeString(points)));
  }
  const int64_t batch = points.size(0);
  if (points.size(1) == 0) return torch::zeros({batch, 3}, points.options());
  const torch::Tensor nonzero = points.ne(0).any(-1);  // B x N
  // Zero points sort last; the lower median of the `count` non-zero values
  // of a coordinate is then at index (count - 1) / 2 (torch.median).
  const torch::Tensor filled =
      points.masked_fill(nonzero.logical_not().unsqueeze(-1),
                         std::numeric_limits<float>::infinity());
  const torch::Tensor sorted = std::get<0>(filled.sort(1));
  const torch::Tensor count = nonzero.sum(1);  // B, int64
  const torch::Tensor index = torch::div(count - 1, 2, "floor").clamp_min(0);
  const torch::Tensor median =
      sorted.gather(1, index.view({batch, 1, 1}).expand({batch, 1, 3}))
          .squeeze(1);
  return torch::where(
      count.gt(0).unsqueeze(-1), median, torch::zeros_like(median));
}

at::Tensor MedianCenter(const at::Tensor& points) {
  return points - MedianOffsets(points).unsqueeze(1);
}

LabelerImpl::LabelerImpl(
    const LabelerOptions& options,
    std::shared_ptr<BackboneImpl> backbone_module,
    std::shared_ptr<NormalizationImpl> normalization_module)
    : options_(options) {
  options_.Validate();
  SOMA_CHECK(backbone_module != nullptr && normalization_module != nullptr)
      << "Labeler needs a backbone and a normalization";
  SOMA_CHECK_EQ(backbone_module->d_model(), options_.d_model);
  encoder = register_module("encoder",
                            PointEncoder(options_.d_model, options_.hidden));
  backbone = register_module("backbone", Backbone(std::move(backbone_module)));
  if (options_.conditioned) {
    // A padded label slot sends its column mass to the dustbin row
    // (kPaddedSlotScore): one score column per slot and a dustbin row, i.e.
    // optimal transport (the spec rejects log_softmax with a ConfigError).
    SOMA_CHECK_EQ(normalization_module->NumScoreColumns(options_.num_labels),
                  options_.num_labels);
    SOMA_CHECK(normalization_module->HasDustbinRow())
        << "a conditioned labeler needs a normalization with a dustbin row";
    label_encoder =
        register_module("label_encoder", LabelEncoder(options_.label_encoder));
    label_head =
        register_module("label_head",
                        ConditionedScoreHead(options_.d_model,
                                             options_.hidden,
                                             options_.cross_layers,
                                             options_.label_encoder.num_heads));
    if (options_.position_loss > 0.0) {
      position_head = register_module(
          "position_head",
          torch::nn::Conv1d(
              torch::nn::Conv1dOptions(options_.d_model, 3, 1).bias(true)));
    }
  } else {
    head = register_module(
        "head",
        ScoreHead(options_.d_model,
                  options_.hidden,
                  normalization_module->NumScoreColumns(options_.num_labels)));
  }
  normalization = register_module(
      "normalization", Normalization(std::move(normalization_module)));
  if (options_.conditioned) {
    layout_descriptors = register_buffer(
        "layout_descriptors",
        torch::zeros(
            {options_.num_labels, options_.label_encoder.descriptor_width}));
  }
}

void LabelerImpl::SetLayout(const torch::Tensor& descriptors) {
  if (!options_.conditioned) {
    throw ConfigError(
        fmt::format("model=soma has a fixed layout of {} labels; use "
                    "model=soma_any_layout to label with a different layout",
                    options_.num_labels));
  }
  if (descriptors.dim() != 2 || descriptors.size(0) > options_.num_labels ||
      descriptors.size(0) < 1 || descriptors.size(1) != descriptor_width()) {
    throw ShapeError(fmt::format(
        "Labeler::SetLayout: descriptors must be K x {} with 1 <= K <= {} "
        "(labels x descriptor width; K <= the model's label slots), got {}",
        descriptor_width(),
        options_.num_labels,
        ShapeString(descriptors)));
  }
  torch::NoGradGuard no_grad;
  // Slots past the layout's K labels stay zero: padded (forward masks them).
  layout_descriptors.zero_();
  layout_descriptors.narrow(0, 0, descriptors.size(0))
      .copy_(descriptors.to(layout_descriptors.options()));
}

LabelerOutput LabelerImpl::forward(const torch::Tensor& points,
                                   bool return_attention) {
  if (!options_.conditioned) return Run(points, nullptr, return_attention);
  const LabelSlots slots = LayoutSlots();
  return Run(points, &slots, return_attention);
}

bool LabelerImpl::HoldsLayout() const {
  return options_.conditioned && layout_descriptors.ne(0).any().item<bool>();
}

LabelSlots LabelerImpl::LayoutSlots() const {
  // A slot whose descriptor row is all zero is padded (a real descriptor
  // holds a unit normal): a layout with fewer labels than the model's slots.
  if (!HoldsLayout()) {
    throw ConfigError(
        "model=soma_any_layout: no layout to label with (Labeler::SetLayout "
        "was not called and the checkpoint holds none: a model trained on "
        "sampled layouts labels the layout it is given, e.g. layout=cmu41)");
  }
  const torch::Tensor present = layout_descriptors.ne(0).any(1);
  return LabelSlots{
      layout_descriptors.unsqueeze(0),
      present.all().item<bool>() ? torch::Tensor() : present.unsqueeze(0)};
}

torch::Tensor LabelerImpl::ConditionedScores(const torch::Tensor& point_keys,
                                             const LabelSlots& slots) {
  const torch::Tensor mask =
      CheckLabelSlots(
          slots, options_.num_labels, descriptor_width(), point_keys.size(0))
          .to(point_keys.device());
  const torch::Tensor labels = label_encoder->EncodeSlots(
      slots.descriptors.to(point_keys.options()), mask);
  return label_head->Scores(point_keys, labels, mask);
}

torch::Tensor LabelerImpl::PositionLoss(const torch::Tensor& point_keys,
                                        const LabelSlots& slots,
                                        const torch::Tensor& labels) {
  if (options_.position_loss <= 0.0) return {};
  const int64_t batch = point_keys.size(0);
  const int64_t n = point_keys.size(2);
  const int64_t l = options_.num_labels;
  CheckLabelSlots(slots, l, descriptor_width(), batch);
  SOMA_CHECK(labels.dim() == 2 && labels.size(0) == batch &&
             labels.size(1) == n)
      << "PositionLoss: labels must be B x N, got " << ShapeString(labels);
  const torch::Tensor ids = labels.to(point_keys.device(), torch::kLong);
  const torch::Tensor labelled = ids.lt(l).logical_and(ids.ge(0));  // B x N
  // The rest position of each point's label slot (a null point's row is
  // gathered from slot 0 and masked out).
  const torch::Tensor positions = slots.descriptors.narrow(2, 0, 3)
                                      .to(point_keys.options())
                                      .expand({batch, l, 3});
  const torch::Tensor target =
      positions.gather(1,
                       ids.masked_fill(labelled.logical_not(), 0)
                           .unsqueeze(2)
                           .expand({batch, n, 3}));  // B N 3
  const torch::Tensor predicted = position_head(point_keys).transpose(1, 2);
  const torch::Tensor weight = labelled.to(point_keys.scalar_type());
  const torch::Tensor per_frame =
      ((predicted - target).square().sum(2) * weight).sum(1) /
      weight.sum(1).clamp_min(1.0);
  return options_.position_loss * per_frame.sum();
}

LabelerOutput LabelerImpl::ForwardSlots(const torch::Tensor& points,
                                        const LabelSlots& slots,
                                        bool return_attention) {
  if (!options_.conditioned) {
    throw ConfigError(
        fmt::format("model=soma has a fixed layout of {} labels; use "
                    "model=soma_any_layout to label with a different layout",
                    options_.num_labels));
  }
  return Run(points, &slots, return_attention);
}

LabelerOutput LabelerImpl::Run(const torch::Tensor& points,
                               const LabelSlots* slots,
                               bool return_attention) {
  if (points.dim() != 3 || points.size(2) != 3) {
    throw ShapeError(fmt::format("Labeler: points must be B x N x 3, got {}",
                                 ShapeString(points)));
  }
  const int64_t n = points.size(1);
  if (slots != nullptr) {  // fail before the backbone's work
    CheckLabelSlots(
        *slots, options_.num_labels, descriptor_width(), points.size(0));
  }
  LabelerOutput out;
  const torch::Tensor centred = MedianCenter(points);
  torch::Tensor features = encoder(centred.transpose(1, 2));
  std::vector<torch::Tensor> attention;
  features =
      backbone->forward(features, return_attention ? &attention : nullptr);
  if (slots != nullptr) {
    out.point_keys = label_head->PointKeys(features);
    out.scores = ConditionedScores(out.point_keys, *slots);
  } else {
    out.scores = head(features);
  }
  out.log_assignment = normalization->forward(out.scores);
  const torch::Tensor point_rows = out.log_assignment.narrow(1, 0, n);
  out.label_confidence = point_rows.exp();
  out.label_ids = point_rows.argmax(-1);
  if (return_attention && !attention.empty())
    out.attention = torch::stack(attention, 1);
  return out;
}

int64_t CountTrainableParameters(const torch::nn::Module& module) {
  int64_t count = 0;
  for (const torch::Tensor& p : module.parameters(/*recurse=*/true)) {
    if (p.requires_grad()) count += p.numel();
  }
  return count;
}

namespace {

/// `name: soma`: the SOMA score predictor with a configurable backbone.
class SomaModelSpec : public ModelSpec {
 public:
  SomaModelSpec(LabelerOptions options, std::shared_ptr<BackboneSpec> backbone)
      : options_(options), backbone_(std::move(backbone)) {}

  Labeler Build(int64_t num_labels,
                Normalization normalization) const override {
    LabelerOptions options = options_;
    options.num_labels = num_labels;
    if (num_labels <= 0) {
      throw ConfigError(fmt::format(
          "Labeler: the marker layout has {} labels; at least one is needed",
          num_labels));
    }
    return Labeler(options,
                   backbone_->Build(options.d_model, options.hidden).ptr(),
                   normalization.ptr());
  }

 private:
  LabelerOptions options_;
  std::shared_ptr<BackboneSpec> backbone_;
};

/// `name: soma_any_layout`: the layout-conditioned labeller (issue #25
/// item 1): the `soma` point branch, a label encoder and a conditioned score
/// head; Sinkhorn only (padded slots need the dustbin row).
class SomaAnyLayoutModelSpec : public ModelSpec {
 public:
  SomaAnyLayoutModelSpec(LabelerOptions options,
                         std::shared_ptr<BackboneSpec> backbone)
      : options_(std::move(options)), backbone_(std::move(backbone)) {}

  Labeler Build(int64_t num_labels,
                Normalization normalization) const override {
    if (num_labels <= 0) {
      throw ConfigError(fmt::format(
          "Labeler: the marker layout has {} labels; at least one is needed",
          num_labels));
    }
    if (dynamic_cast<const SinkhornImpl*>(normalization.get()) == nullptr) {
      throw ConfigError(
          "Invalid configuration. normalization: model=soma_any_layout needs "
          "normalization=sinkhorn (padded label slots go to the dustbin row)");
    }
    LabelerOptions options = options_;
    options.num_labels = num_labels;
    return Labeler(options,
                   backbone_->Build(options.d_model, options.hidden).ptr(),
                   normalization.ptr());
  }
  bool conditioned() const override { return true; }

 private:
  LabelerOptions options_;
  std::shared_ptr<BackboneSpec> backbone_;
};

/// Reads `d_model`, `hidden` and `backbone` of a `soma`-style model node.
std::shared_ptr<BackboneSpec> ReadPointBranch(const ConfigNode& node,
                                              ConfigReader& reader,
                                              BuildContext& ctx,
                                              LabelerOptions* options) {
  reader.Read("d_model", &options->d_model);
  reader.Read("hidden", &options->hidden);
  reader.Check("d_model", options->d_model > 0, "d_model > 0");
  reader.Check("hidden", options->hidden > 0, "hidden > 0");
  const ConfigNode* backbone_node = reader.Child("backbone");
  if (backbone_node == nullptr || !backbone_node->IsMap()) {
    throw ConfigError(
        fmt::format("Invalid configuration. {}.backbone: expected a map "
                    "with 'name' naming a "
                    "backbone ({})",
                    node.path().empty() ? "model" : node.path(),
                    fmt::join(GetRegistry<BackboneSpec>().Keys(), ", ")));
  }
  std::shared_ptr<BackboneSpec> backbone =
      Instantiate<BackboneSpec>(*backbone_node, ctx);
  backbone->CheckCompatible(options->d_model, backbone_node->path());
  return backbone;
}

}  // namespace

void RegisterModelSpecs() {
  GetRegistry<ModelSpec>().Register(
      "soma", [](const ConfigNode& node, BuildContext& ctx) {
        ConfigReader reader(node);
        LabelerOptions options;
        std::shared_ptr<BackboneSpec> backbone =
            ReadPointBranch(node, reader, ctx, &options);
        reader.Finish();
        return std::make_unique<SomaModelSpec>(options, std::move(backbone));
      });
  GetRegistry<ModelSpec>().Register(
      "soma_any_layout", [](const ConfigNode& node, BuildContext& ctx) {
        ConfigReader reader(node);
        LabelerOptions options;
        options.conditioned = true;
        std::shared_ptr<BackboneSpec> backbone =
            ReadPointBranch(node, reader, ctx, &options);
        const ConfigNode* label_node = reader.Child("label_encoder");
        reader.Read("cross_layers", &options.cross_layers);
        reader.Check(
            "cross_layers", options.cross_layers >= 0, "cross_layers >= 0");
        reader.Read("position_loss", &options.position_loss);
        reader.Check("position_loss",
                     options.position_loss >= 0.0,
                     "position_loss >= 0");
        reader.Finish();
        LabelEncoderOptions& label = options.label_encoder;
        int num_joints = kNumCoreJoints;
        if (label_node != nullptr) {
          ConfigReader label_reader(*label_node);
          label_reader.Read("num_joints", &num_joints);
          label_reader.Read("hidden", &label.hidden);
          label_reader.Read("num_layers", &label.num_layers);
          label_reader.Read("num_heads", &label.num_heads);
          label_reader.Read("fourier_bands", &label.fourier_bands);
          label_reader.Read("relative_bias", &label.relative_bias);
          label_reader.Check("num_joints", num_joints > 0, "num_joints > 0");
          label_reader.Check("hidden", label.hidden > 0, "hidden > 0");
          label_reader.Check(
              "num_layers", label.num_layers >= 0, "num_layers >= 0");
          label_reader.Check(
              "num_heads",
              label.num_heads > 0 && options.d_model % label.num_heads == 0,
              "num_heads > 0 and d_model % num_heads == 0");
          label_reader.Check(
              "fourier_bands",
              label.fourier_bands >= 0 &&
                  label.fourier_bands <= kMaxFourierBands,
              fmt::format("0 <= fourier_bands <= {}", kMaxFourierBands));
          label_reader.Check(
              "relative_bias", label.relative_bias >= 0, "relative_bias >= 0");
          label_reader.Finish();
        }
        label.d_model = options.d_model;
        label.descriptor_width = LabelDescriptorWidth(num_joints);
        return std::make_unique<SomaAnyLayoutModelSpec>(options,
                                                        std::move(backbone));
      });
  RegisterConfigGroup<ModelSpec>("model");
}

Labeler BuildLabeler(const ConfigNode& model,
                     const ConfigNode& normalization,
                     int64_t num_labels,
                     BuildContext& ctx) {
  const std::unique_ptr<ModelSpec> spec = Instantiate<ModelSpec>(model, ctx);
  std::shared_ptr<NormalizationImpl> norm =
      Instantiate<NormalizationImpl>(normalization, ctx);
  return spec->Build(num_labels, Normalization(std::move(norm)));
}

Labeler BuildLabeler(const ConfigNode& model,
                     const ConfigNode& normalization,
                     int64_t num_labels) {
  BuildContext ctx;
  return BuildLabeler(model, normalization, num_labels, ctx);
}

}  // namespace soma
