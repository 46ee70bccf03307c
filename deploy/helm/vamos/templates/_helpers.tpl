{{- define "vamos.name" -}}
{{- .Chart.Name | trunc 63 | trimSuffix "-" -}}
{{- end -}}

{{- define "vamos.fullname" -}}
{{- if contains .Chart.Name .Release.Name -}}
{{- .Release.Name | trunc 63 | trimSuffix "-" -}}
{{- else -}}
{{- printf "%s-%s" .Release.Name .Chart.Name | trunc 63 | trimSuffix "-" -}}
{{- end -}}
{{- end -}}

{{- define "vamos.labels" -}}
app.kubernetes.io/name: {{ include "vamos.name" . }}
app.kubernetes.io/instance: {{ .Release.Name }}
app.kubernetes.io/version: {{ .Chart.AppVersion | quote }}
app.kubernetes.io/managed-by: {{ .Release.Service }}
helm.sh/chart: {{ printf "%s-%s" .Chart.Name .Chart.Version }}
{{- end -}}

{{- define "vamos.selectorLabels" -}}
app.kubernetes.io/name: {{ include "vamos.name" . }}
app.kubernetes.io/instance: {{ .Release.Name }}
{{- end -}}

{{- define "vamos.secretName" -}}
{{- if .Values.tokens.existingSecret -}}
{{- .Values.tokens.existingSecret -}}
{{- else -}}
{{- include "vamos.fullname" . -}}
{{- end -}}
{{- end -}}

{{- define "vamos.checks" -}}
{{- if and .Values.persistence.enabled (or (gt (int .Values.replicaCount) 1) .Values.autoscaling.enabled) -}}
{{- fail "vamos locks its data directory: with persistence.enabled, replicaCount must be 1 and autoscaling disabled" -}}
{{- end -}}
{{- if and (not .Values.tokens.existingSecret) (not .Values.tokens.admin) -}}
{{- fail "set tokens.admin (and tokens.robot) or tokens.existingSecret: the server refuses non-loopback addresses without tokens" -}}
{{- end -}}
{{- end -}}
